"""The loss, its normal equations and the full-table error."""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
import numpy as np
import pytest

from brdffit import models
from brdffit.fitting import loss, pipeline, sampling
from brdffit.fitting import problem as fitting
from brdffit.request import FitRequest
from data_synth import make_table
from tests.cli_helpers import run_main
from tests.compiled_models import check_jit, evaluate
from tests.truths import TRUTH

pytestmark = pytest.mark.unit

# The two sides of each comparison, compiled: op by op, every primitive of a Jacobian
# compiles on its own (seconds per model in a new process), and fits run them compiled.
normal_equations = check_jit(loss.normal_equations, comparison=True)
generic_normal_equations = check_jit(loss._generic_normal_equations, comparison=True)
one_pass_normal_equations = check_jit(loss._normal_equations, comparison=True)
# the metrics and the loss alike: one compiled program each, as the fit runs them
sum_squares = eqx.filter_jit(loss.sum_squares)


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
    fast = normal_equations(u, (m, data))
    plain = generic_normal_equations(u, (m, data))
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


def test_full_table_metrics_equal_their_definition(noisy_ggx):
    """The fused, blocked full-table metrics (the one implementation, for tables and
    sample lists alike) are docs/results.md's definitions, written out here in numpy
    over every bin."""
    m = models.get("ggx")
    u = jnp.asarray(m.unconstrain(TRUTH["ggx"]))
    w = sampling.bin_weights(sampling.usable_bins(noisy_ggx).usable)
    a = fitting.full_table_metrics(noisy_ggx, m, u, w, dtype=jnp.float64)
    frame = fitting.full_table_data(noisy_ggx, w).frame
    cos_i = np.maximum(np.asarray(frame.cos_i), 0.0)
    fit_cos = np.maximum(np.asarray(m.eval_channels(m.constrain(u), frame)), 0.0) * cos_i
    meas_cos = np.maximum(noisy_ggx.rgb.reshape(3, -1), 0.0) * cos_i

    def rmse(d):
        return np.sqrt(np.sum(w * d * d) / 3.0)

    def cube(x):
        return np.cbrt(x + 1e-6)

    peak = np.argmax(np.where(w > 0, meas_cos.sum(axis=0), -np.inf))
    b = {"log_rmse": rmse(np.log1p(fit_cos) - np.log1p(meas_cos)),
         "cube_root_rmse": rmse(cube(fit_cos) - cube(meas_cos)),
         "rmse_cos": rmse(fit_cos - meas_cos),
         "rel_peak_error": np.max(np.abs(fit_cos[:, peak] - meas_cos[:, peak])
                                  / np.maximum(meas_cos[:, peak], 1e-12))}
    for k in a:
        assert a[k] == pytest.approx(float(b[k]), rel=1e-8), k


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


@pytest.mark.slow
@pytest.mark.parametrize("name", ["ggx", "ggx2", "oren_nayar"])
def test_blocked_normal_equations_equal_one_pass(name, noisy_ggx):
    """Every bin (1.46M samples) is summed in blocks; the sums are the same."""
    c = sampling.usable_bins(noisy_ggx)
    s = sampling.stratified_sample(sampling.bin_weights(c.usable), None)
    assert loss._block_size(s.index.size) is not None
    data = fitting.sample_data(noisy_ggx, s.index, s.weight)
    m = models.get(name)
    u = jnp.asarray(m.unconstrain({**TRUTH, **MORE}[name])) + 0.2
    blocked = normal_equations(u, (m, data))
    one_pass = one_pass_normal_equations(u, m, data)
    for a, b in zip(blocked, one_pass):
        np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=1e-10, atol=1e-16)


# -- the loss as a choice ----------------------------------------------------------------


@pytest.mark.parametrize("choice", loss.LOSSES)
def test_structured_normal_equations_equal_plain_jacobian_for_every_loss(choice, noisy_ggx):
    c = sampling.usable_bins(noisy_ggx)
    s = sampling.stratified_sample(sampling.bin_weights(c.usable), 2048)
    data = fitting.sample_data(noisy_ggx, s.index, s.weight, loss=choice)
    assert data.loss_name == choice
    m = models.get("ggx")
    u = jnp.asarray(m.unconstrain(TRUTH["ggx"])) + 0.3
    fast = normal_equations(u, (m, data))
    plain = generic_normal_equations(u, (m, data))
    for a, b in zip(fast, plain, strict=True):
        np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=1e-9, atol=1e-14)


@pytest.mark.parametrize("choice", loss.LOSSES)
def test_every_loss_recovers_the_truth_and_reports_every_metric(choice):
    table, _ = make_table("ggx", TRUTH["ggx"])
    r = pipeline.fit(table, "ggx", loss=choice, samples=2048)
    assert r.converged and r.loss == choice
    for name in ("kd", "ks"):
        np.testing.assert_allclose(r.params[name], TRUTH["ggx"][name], rtol=1e-3, atol=1e-5)
    np.testing.assert_allclose(r.params["alpha"], TRUTH["ggx"]["alpha"], rtol=1e-3)
    metric = loss.LOSS_METRIC[choice]
    assert set(r.error) == {"log_rmse", "cube_root_rmse", "rmse_cos", "rel_peak_error",
                            "psnr_db", f"sample_{metric}"}
    assert r.error[f"sample_{metric}"] < 1e-4 and r.error["psnr_db"] > 40
    assert r.error["log_rmse"] < 1e-4


def test_each_loss_minimises_its_own_metric():
    """A model that cannot fit the table exactly (Blinn-Phong on GGX): each loss
    ends lowest on the metric it optimised, so the choice matters and is reported.
    The render loss has no full-table metric: it is judged on its own data."""
    table, _ = make_table("ggx", {**TRUTH["ggx"], "alpha": 0.35, "f0": 0.1})
    fits = {c: pipeline.fit(table, "blinn_phong", loss=c, samples=4096) for c in loss.LOSSES}
    for c, r in fits.items():
        if c == "render":
            continue
        metric = loss.LOSS_METRIC[c]
        for other in fits.values():
            assert r.error[metric] <= other.error[metric] * 1.01, (c, metric)
    m = models.get("blinn_phong")
    prep = fitting.prepare(table, None, 4096, 0, "float64", "render")
    render_loss_of = {c: float(loss.sum_squares(jnp.asarray(m.unconstrain(r.params)), m,
                                                prep.data)) for c, r in fits.items()}
    assert render_loss_of["render"] == min(render_loss_of.values()), render_loss_of
    exponents = sorted(r.params["n"] for r in fits.values())
    assert exponents[-1] > 1.02 * exponents[0], exponents  # the choice changes the fit


def test_an_unknown_loss_is_refused_everywhere():
    from brdffit.errors import FitInputError
    from brdffit.fitting.options import FitOptions

    table, _ = make_table("lambert", TRUTH["lambert"])
    with pytest.raises(FitInputError, match="unknown loss 'l1'; choose one of log, cube_root"):
        pipeline.fit(table, "lambert", loss="l1")
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

    from api import tasks
    from api.routes.fits import FitResultOut
    from brdffit.batch.job import run_batch
    from brdffit.batch.store import read_results
    from brdffit.io import merl
    from brdffit.selection import chosen_result as best_result

    table, _ = make_table("ggx", {**TRUTH["ggx"], "alpha": 0.35}, noise=0.02, seed=2)
    path = tmp_path / "t.binary"
    merl.write(path, table)
    r = run_main("brdffit.cli", "fit", str(path), "--model", "ggx", "--loss", "cube_root",
                 "--samples", "2048", "--json")
    assert r.returncode == 0, r.stderr
    cli = json.loads(r.stdout)
    assert cli["loss"] == "cube_root" and "sample_cube_root_rmse" in cli["error"]

    out = tasks.fit_models(str(path), "t.binary", FitRequest.of("ggx", loss="linear_cos",
                                                                samples=2048).to_dict())
    served = FitResultOut.model_validate(best_result(out.value))
    assert served.loss == "linear_cos" and "sample_rmse_cos" in served.error

    run_batch([str(path)], FitRequest.of("ggx", loss="cube_root", samples=2048),
              tmp_path / "r.h5", workers=0, progress=False)
    stored = read_results(tmp_path / "r.h5")["tables"][0]["fits"]["ggx"]["fit"]
    assert stored["loss"] == "cube_root" and stored["uncertainty"]["std_error"]["alpha"] > 0
    for name, v in cli["params"].items():  # the same fit from the CLI and the batch
        np.testing.assert_allclose(stored["params"][name], v, rtol=1e-9)


# -- the render loss -----------------------------------------------------------------------


def _numpy_render_loss(table, index, weight, params, model):
    """The render loss of docs/fitting.md written out in numpy, from the table's values:
    per channel the exposure 0.35 / weighted median of f cos_i over the bins, the tone
    curve of the exposed f cos_i, the weighted squared difference; plus, per channel,
    ENERGY_WEIGHT (0.05) log^2 of the ratio of the weighted means of f cos_i (fit over table)."""
    from brdffit.io.grid import bin_grid

    g = bin_grid()
    cos_i = np.maximum(g.cos_i[index], 0.0)
    meas = np.maximum(table.rgb.reshape(3, -1)[:, index], 0.0) * cos_i
    p = {k: np.asarray(v, np.float64) for k, v in params.items()}
    fit_f = np.asarray(evaluate(model, p, g.wi[index], g.wo[index])).T  # (3, S), compiled
    fit = np.maximum(fit_f, 0.0) * cos_i
    used = weight > 0
    level = []
    for c in range(3):
        order = np.argsort(meas[c][used])
        cum = np.cumsum(weight[used][order])
        median = meas[c][used][order][np.searchsorted(cum, cum[-1] / 2)]
        level.append(max(median, 0.1 * (meas[c] @ weight) / weight.sum()))
    level = np.maximum(level, max(level) / 30)  # no channel exposed 30x the brightest
    e = 0.35 / np.array(level)[:, None]

    def curve(y):
        v = y / (1 + y)
        return ((v + 0.003) ** (1 / 2.2) - 0.003 ** (1 / 2.2)) / (
            1.003 ** (1 / 2.2) - 0.003 ** (1 / 2.2))

    d = curve(e * fit) - curve(e * meas)
    ratio = (fit @ weight) / (meas @ weight)
    return float(np.sum(weight * d * d) + 0.05 * np.sum(np.log(ratio) ** 2))


def test_render_loss_value_is_the_numpy_definition(noisy_ggx):
    m = models.get("ggx")
    prep = fitting.prepare(noisy_ggx, None, 4096, 0, "float64", "render")
    params = {**TRUTH["ggx"], "alpha": 0.2, "kd": [0.3, 0.05, 0.01]}
    got = float(sum_squares(jnp.asarray(m.unconstrain(params)), m, prep.data))
    want = _numpy_render_loss(noisy_ggx, prep.sample_set.index, prep.sample_set.weight,
                              params, m)
    assert got == pytest.approx(want, rel=1e-9)
    # the solver sees only bins of the rendered views, and the views see both lobes
    from brdffit.fitting import render_loss

    seen = render_loss.view_bin_weight()
    assert np.all(seen[prep.sample_set.index[prep.sample_set.weight > 0]] > 0)
    # every usable bin is still judged by the full-table metrics
    assert np.count_nonzero(prep.weight) == np.count_nonzero(
        sampling.usable_bins(noisy_ggx).usable)


def test_render_loss_exposes_each_channel_from_the_table():
    """A channel 20x darker has a 20x larger exposure: its relative error counts."""
    base = {"kd": [0.4, 0.1, 0.02], "ks": [0.2, 0.2, 0.2], "alpha": 0.3, "f0": 0.5}
    table = make_table("ggx", base)[0]
    prep = fitting.prepare(table, None, 4096, 0, "float64", "render")
    e = np.asarray(prep.data.exposure)[:, 0]
    assert e[2] > 5 * e[0] and e[1] > 2 * e[0]
    # a 10% error in the dark blue channel costs about what one in red does
    m = models.get("ggx")

    def cost(channel):
        kd = list(base["kd"])
        kd[channel] *= 1.1
        ks = [0.2, 0.2, 0.2]
        ks[channel] *= 1.1
        u = jnp.asarray(m.unconstrain({**base, "kd": kd, "ks": ks}))
        return float(loss.sum_squares(u, m, prep.data))

    assert 0.3 < cost(2) / cost(0) < 3
    logp = fitting.prepare(table, None, 4096, 0, "float64", "log")

    def log_cost(channel):
        kd = list(base["kd"])
        kd[channel] *= 1.1
        ks = [0.2, 0.2, 0.2]
        ks[channel] *= 1.1
        u = jnp.asarray(m.unconstrain({**base, "kd": kd, "ks": ks}))
        return float(loss.sum_squares(u, m, logp.data))

    assert log_cost(2) / log_cost(0) < 0.3 * cost(2) / cost(0)  # where the log loss is not


@pytest.mark.parametrize("name", ["ggx", "ggx2", "lambert", "blinn_phong"])
def test_render_loss_gradients_are_finite(name, noisy_ggx):
    import jax

    m = models.get(name)
    prep = fitting.prepare(noisy_ggx, None, 2048, 0, "float64", "render")
    p = {**TRUTH, **MORE}[name]
    # compiled once (op by op, every primitive compiles on its own in a new process)
    gradient = jax.jit(lambda u: jax.grad(loss.sum_squares)(u, m, prep.data))
    for shift in (-12.0, -3.0, 0.0, 3.0, 12.0):  # down to black, up to far too bright
        u = jnp.asarray(m.unconstrain(p)) + shift
        g = gradient(u)
        assert np.all(np.isfinite(np.asarray(g))), (name, shift)
        for a in normal_equations(u, (m, prep.data)):
            assert np.all(np.isfinite(np.asarray(a))), (name, shift)


def test_render_loss_tone_curve_and_its_inverse():
    y = np.concatenate([[0.0], np.geomspace(1e-8, 1e6, 200)])
    t = np.asarray(loss.tone(jnp.asarray(y)))
    assert abs(t[0]) < 1e-15 and np.all(np.diff(t) > 0) and t[-1] < 1  # smooth, no clip
    np.testing.assert_allclose(np.asarray(loss.tone_inverse(jnp.asarray(t))), y,
                               rtol=1e-6, atol=1e-12)
    slope = np.asarray(loss.tone_slope(jnp.asarray(y[:-1])))
    numeric = np.gradient(t, y)[:-1]
    np.testing.assert_allclose(slope[50:-20], numeric[50:-20], rtol=0.05)
    assert np.isfinite(slope[0]) and slope[0] > 0


def test_render_loss_fits_share_one_compiled_program(caplog):
    """Data travels through args (exposures included): a second table with the same
    settings compiles nothing."""
    import logging

    import jax

    first = make_table("ggx", {**TRUTH["ggx"], "alpha": 0.2}, noise=0.02, seed=4)[0]
    second = make_table("ggx", {"kd": [0.05, 0.3, 0.6], "ks": [0.5, 0.2, 0.1],
                                "alpha": 0.4, "f0": 0.3}, noise=0.02, seed=5)[0]
    pipeline.fit(first, "ggx", loss="render", samples=2048)
    jax.config.update("jax_log_compiles", True)
    try:
        with caplog.at_level(logging.DEBUG):
            r = pipeline.fit(second, "ggx", loss="render", samples=2048)
    finally:
        jax.config.update("jax_log_compiles", False)
    compiles = [rec.getMessage() for rec in caplog.records if "Compiling" in rec.getMessage()]
    assert r.converged and compiles == []


def test_render_loss_with_a_scene_uses_the_scene_views(noisy_ggx):
    from brdffit.fitting.scene import Scene

    scene = Scene.preset("camera-normal")
    prep = fitting.prepare(noisy_ggx, scene.bin_weight(), 2048, 0, "float64", "render")
    used = prep.sample_set.index[prep.sample_set.weight > 0]
    assert np.all(scene.bin_weight()[used] > 0)
    r = pipeline.fit(noisy_ggx, "ggx", loss="render", samples=2048,
                    bin_weight=scene.bin_weight())
    assert r.converged and r.loss == "render"


@pytest.mark.slow  # ~5 s; the quick tier keeps the log loss's trip through every door
def test_the_render_loss_reaches_the_cli_the_service_job_and_the_batch(tmp_path):
    import json

    from api import tasks
    from api.routes.fits import FitResultOut
    from brdffit.batch.job import run_batch
    from brdffit.batch.store import read_results
    from brdffit.io import merl
    from brdffit.selection import chosen_result as best_result

    table, _ = make_table("ggx", {**TRUTH["ggx"], "alpha": 0.35}, noise=0.02, seed=2)
    path = tmp_path / "t.binary"
    merl.write(path, table)
    r = run_main("brdffit.cli", "fit", str(path), "--model", "ggx", "--loss", "render",
                 "--samples", "2048", "--json")
    assert r.returncode == 0, r.stderr
    cli = json.loads(r.stdout)
    assert cli["loss"] == "render" and "sample_render_rmse" in cli["error"]
    out = tasks.fit_models(str(path), "t.binary", FitRequest.of("ggx", loss="render",
                                                                samples=2048).to_dict())
    served = FitResultOut.model_validate(best_result(out.value))
    assert served.loss == "render"
    run_batch([str(path)], FitRequest.of("ggx", loss="render", samples=2048),
              tmp_path / "r.h5", workers=0, progress=False)
    stored = read_results(tmp_path / "r.h5")["tables"][0]["fits"]["ggx"]["fit"]
    assert stored["loss"] == "render"
    for name, v in cli["params"].items():
        np.testing.assert_allclose(stored["params"][name], v, rtol=1e-9)


def test_one_pass_of_several_models_is_each_models_own_pass(noisy_ggx):
    """auto measures its candidates in one pass over the table: each model's metrics
    are those of its own pass (float32 sums in another order: 1e-6 relative), and a
    model that overflows float32 is measured again in float64 alone, the others as
    they were."""
    w = sampling.bin_weights(sampling.usable_bins(noisy_ggx).usable)
    names = ("lambert", "phong", "ggx", "ggx2")
    fits = [(models.get(n), models.get(n).unconstrain({**TRUTH, **MORE}[n])) for n in names]
    huge = models.get("ggx").unconstrain({**TRUTH["ggx"], "ks": [1e30] * 3})
    fits.append((models.get("ggx"), huge))  # (f cos)^2 ~1e60: past float32
    together = fitting.full_table_metrics_of(noisy_ggx, fits, w)
    assert len(together) == len(fits)
    for (m, u), metrics in zip(fits, together, strict=True):
        alone = fitting.full_table_metrics(noisy_ggx, m, u, w)
        assert set(metrics) == set(alone)
        for k in alone:
            assert metrics[k] == pytest.approx(alone[k], rel=1e-6), (m.name, k)
    assert together[-1]["rmse_cos"] > 1e28  # measured, in float64
    assert together[0]["log_rmse"] > together[2]["log_rmse"]  # lambert on a ggx table


@pytest.mark.parametrize("name", [
    # each case compiles two Jacobians of its model under two losses (every registry
    # model took the full suite 300 s): RGB and scalar parameters, linear and log
    # ranges, a layer over a base, and one of MaterialX's big models
    # (the quick tier keeps the first two: its 4 minutes)
    "ggx", "gltf_sheen",
    *(pytest.param(name, marks=pytest.mark.slow)
      for name in ("principled_clearcoat", "rough_conductor", "standard_surface_coat"))])
def test_the_jacobian_one_parameter_at_a_time_is_jacfwds(name):
    """The residuals' Jacobian taken one parameter at a time (the solver's, for every
    model without the closed form) is ``jacfwd``'s of the whole, to rounding, at a
    random point and on random directions."""
    import jax

    model = models.get(name)
    rng = np.random.default_rng(5)
    v = rng.normal(size=(2, 64, 3))
    v[..., 2] = np.abs(v[..., 2]) + 0.05
    v /= np.linalg.norm(v, axis=-1, keepdims=True)
    from brdffit.models.frame import shading_frame

    frame = shading_frame(jnp.asarray(v[0]), jnp.asarray(v[1]))
    target, weight = jnp.asarray(rng.uniform(0.0, 1.0, (3, 64))), jnp.full(64, 1.0 / 64)
    u = jnp.asarray(rng.normal(size=model.n_params) * 0.5)
    # the log loss's residuals, and the render loss's with its energy row (3, S + 1)
    for data in (loss.LossData(frame=frame, target=target, weight=weight, loss="log"),
                 loss.LossData(frame=frame, target=target, weight=weight, loss="render",
                               exposure=jnp.full((3, 1), 2.0), energy=jnp.full((3, 1), 0.2))):
        # compiled, each a program: op by op, their thousands of small programs took
        # longer to dispatch (and to load from the cache) than these take to compile
        r, jac = check_jit(loss.residual_jacobian, comparison=True)(u, (model, data))
        whole = check_jit(jax.jacfwd(
            lambda w, d: loss.residuals(w, (model, d)).reshape(-1)), comparison=True)(u, data)
        assert jac.shape == whole.shape and whole.shape[1] == model.n_params
        np.testing.assert_allclose(np.asarray(r),
                                   np.asarray(loss.residuals(u, (model, data))).ravel(),
                                   rtol=1e-12, atol=1e-15)
        scale = float(np.max(np.abs(np.asarray(whole))))
        np.testing.assert_allclose(np.asarray(jac), np.asarray(whole), rtol=1e-9,
                                   atol=1e-12 * max(scale, 1.0))


def test_render_loss_sees_a_near_mirror_peak_in_the_energy_it_holds():
    """The render loss's views weigh every bin a lit sphere reflects in, the peak rows
    of theta_h too: a 256-px picture saw none of rows 0 and 1, where a fit could then put
    any energy unseen (a spike carrying half of color-changing-paint3's ggx2 sphere)."""
    from brdffit.fitting import render_loss
    from brdffit.io.grid import bin_grid

    area = render_loss.view_area()
    rows = area.reshape(90, -1).sum(axis=1)
    assert np.all(rows > 0)
    # a near-mirror lobe: the subsample's energy is the views' own, every bin's
    table = make_table("ggx", {"kd": [0.02, 0.02, 0.02], "ks": [0.5, 0.4, 0.3],
                               "alpha": 0.002, "f0": 0.9})[0]
    prep = fitting.prepare(table, None, 16384, 0, "float64", "render")
    index = prep.sample_set.index[prep.sample_set.weight > 0]
    assert set(range(4)) <= set(np.unique(index // (90 * 180)).tolist())
    x = np.nan_to_num(table.rgb.reshape(3, -1)) * np.maximum(bin_grid().cos_i, 0.0)
    usable = sampling.usable_bins(table).usable
    w = np.where(usable, area, 0.0)
    every_bin = x @ w / w.sum()
    assert np.asarray(prep.data.energy)[:, 0] == pytest.approx(every_bin, rel=0.01)
