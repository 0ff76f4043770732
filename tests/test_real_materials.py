"""Real materials (rebuilt on the fly from the shipped neural BRDFs): the invariants
a fit must keep where users live, not only on tables our own models wrote.

- a richer model never ends worse than the model it contains;
- every fit that says converged passes the optimality test, checked here
  independently (plain autodiff Jacobian, numpy least squares);
- a default fit lands within 1.01x of a best-effort fit (six starts, then every
  bin).

The three materials are those on which the first solver stopped early while
saying converged (issue 10): a metallic paint, a felt, a plastic.
"""

from __future__ import annotations

import jax
import numpy as np
import pytest

from brdffit import fit, models
from brdffit.fitting import problem as fitting
from brdffit.fitting.loss import residuals
from brdffit.fitting.sampling import DEFAULT_SAMPLES, bin_weights, stratified_sample, usable_bins
from brdffit.fitting.solver import MAX_STEP
from data_synth import nbrdf
from tests.compiled_models import check_jit

pytestmark = pytest.mark.system

MATERIALS = ("gold-metallic-paint", "pink-felt", "red-plastic")
MODELS = ("lambert", "oren_nayar", "blinn_phong", "beckmann", "ggx", "ggx2")


@pytest.fixture(scope="module")
def real():
    tables = {name: nbrdf.make_table(name) for name in MATERIALS}
    fits = {(name, m): fit(t, m) for name, t in tables.items() for m in MODELS}
    return tables, fits


@pytest.mark.parametrize("name", MATERIALS)
@pytest.mark.parametrize(("child", "parent"), [("ggx2", "ggx"), ("oren_nayar", "lambert")])
def test_nested_model_never_loses(real, name, child, parent):
    _, fits = real
    assert fits[name, child].log_rmse <= 1.001 * fits[name, parent].log_rmse


def _independent_decrement(table, model_name, params, samples=DEFAULT_SAMPLES, seed=0):
    """(decrement, loss) at ``params`` on the fit's own samples: the reduction of the
    sum of squares that the linearised residuals still promise over the free
    coordinates, by an SVD-based least squares on the full Jacobian."""
    m = models.get(model_name)
    ss = stratified_sample(bin_weights(usable_bins(table).usable), samples, seed)
    data = fitting.sample_data(table, ss.index, ss.weight)
    u = np.asarray(m.unconstrain(m.check_params(params)))

    def r_of(v, d):  # the data as arguments: one program per model, not per table
        return residuals(v, (m, d)).ravel()

    r = np.asarray(check_jit(r_of)(u, data))
    jac = np.asarray(check_jit(jax.jacfwd(r_of))(u, data))
    side = np.asarray(m.bound_side(u))
    # a coordinate in a flat tail whose descent and Gauss-Newton step point out of
    # range, by more than one capped step, is held at its bound (KKT)
    full_step, *_ = np.linalg.lstsq(jac, -r, rcond=1e-10)
    free = ~((side != 0) & (-(jac.T @ r) * side >= 0) & (full_step * side >= MAX_STEP))
    step, *_ = np.linalg.lstsq(jac[:, free], -r, rcond=1e-10)
    return float(np.sum((jac[:, free] @ step) ** 2)), float(r @ r)


@pytest.mark.parametrize("name", MATERIALS)
@pytest.mark.parametrize("model", ["lambert", "oren_nayar", "beckmann", "ggx", "ggx2"])
def test_converged_means_the_optimality_test_holds(real, name, model):
    tables, fits = real
    r = fits[name, model]
    assert r.converged, f"{name} {model}: {r.result} after {r.steps} steps"
    dec, loss = _independent_decrement(tables[name], model, r.params)
    # brdffit stops at 1e-7 of the loss; an undamped solve of the same linear model
    # agrees to within the conditioning of the unidentified directions
    assert dec <= 1e-5 * loss, (name, model, dec / loss)


def test_a_stopped_fit_is_not_converged(real):
    tables, _ = real
    r = fit(tables["gold-metallic-paint"], "ggx", max_steps=3)  # needs ~30 steps
    assert not r.converged
    assert r.result == "nonlinear_max_steps_reached"
    dec, loss = _independent_decrement(tables["gold-metallic-paint"], "ggx", r.params)
    assert dec > 1e-7 * loss  # and it really is not at an optimum


@pytest.mark.parametrize("name", MATERIALS)
@pytest.mark.parametrize("model", ["ggx", "ggx2"])
def test_default_fit_within_one_percent_of_best_effort(real, name, model):
    tables, fits = real
    table, default = tables[name], fits[name, model]
    # Six starts find the basins; the every-bin refinement then reaches that basin's
    # optimum on the whole table. A multi-start on 4x the samples found the same best
    # here to 6 digits in all six cases, in ~2.4x the time (ggx2 on pink-felt: 22 s
    # against 7 s, on 2 cores), so the samples are the default's.
    many = fit(table, model, starts=6, max_steps=1000)
    start = min((default, many), key=lambda r: r.log_rmse)
    every_bin = fit(table, model, samples=None, init=start.params, max_steps=60)
    best = min(r.log_rmse for r in (default, many, every_bin))
    assert default.log_rmse <= 1.01 * best, (default.log_rmse, best)


# -- the verdict on real materials (issue 38) --------------------------------------------


@pytest.mark.parametrize("name", ["gold-metallic-paint", "blue-metallic-paint", "red-plastic"])
def test_auto_with_the_render_loss_chooses_what_looks_best(name):
    """auto under the render loss chooses within 0.5 dB of the best-looking candidate
    under the render loss's eight lights (on gold-metallic-paint it chose phong, 22.1
    dB, over ggx at 25.5 dB, ranking by log_rmse; on blue-metallic-paint, ranked on the
    verdict's two lights, it chose phong, 1.9 dB further off than ggx under
    bench.render_loss's independent lights), and the chosen fit's next steps put what
    was measured first."""
    from brdffit.selection import select

    sel = select(nbrdf.make_table(name), loss="render")
    fitted = [r for r in sel.ranking if r["status"] != "failed"]
    assert all(r["views_psnr_db"] is not None for r in fitted)
    best = max(r["views_psnr_db"] for r in fitted)
    assert sel.rule == "render_psnr_db"
    assert sel.row["views_psnr_db"] >= best - 0.5, sel.reason
    look = sel.chosen_fit.quality
    measured = [s for s in look["next"] if s["gain_db"] is not None]
    assert all(s["gain_db"] > 0 for s in measured)
    worse = {r["model"] for r in fitted if r["views_psnr_db"] <= sel.row["views_psnr_db"]}
    assert not {s["try"].removeprefix("--model ") for s in look["next"]} & worse


def test_an_undetermined_parameter_names_its_real_cause():
    """pink-felt under the physical bounds holds ks at 1 in every channel: alpha is
    then a lobe at its limit, not 'no lobe: ks within 2 standard errors of 0'."""
    r = fit(nbrdf.make_table("pink-felt"), "ggx", physical=True)
    u = r.uncertainty
    assert all(u["at_bound"]["ks"])
    assert not any("no lobe" in why for why in u["why"].values()), u["why"]


def test_a_nested_fit_that_leaves_its_parent_again_is_not_called_the_parent():
    """Under the render loss, color-changing-paint3's ggx2 ends at twice ggx's
    log_rmse; refined from ggx's optimum it comes back to the same near-mirror spike.
    The note says so, with both sphere PSNRs: it may not call that ggx's optimum."""
    table = nbrdf.make_table("color-changing-paint3")
    base = fit(table, "ggx", loss="render")
    two = fit(table, "ggx2", loss="render", parent_fit=base)
    assert two.log_rmse > 1.5 * base.log_rmse
    note = next(n for n in two.notes if "worse than ggx's on the table" in n)
    assert "came back to log_rmse" in note and "this is ggx's optimum" not in note
    assert f"{two.error['psnr_db']:.1f} dB against ggx's {base.error['psnr_db']:.1f} dB" in note
    assert two.params["ks2"][0] > 1e-3  # what ggx2 adds is on: not ggx's optimum
