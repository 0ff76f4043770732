"""The physically bounded fit (brdffit.fitting.physical): its coarse albedo against the
exact one, its ranges, a fit that needs them and one that does not, the clamp, the
report, strict JSON, and a default fit left as it was."""

from __future__ import annotations

import json

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from brdffit import FitInputError, FitResult, fit, models
from brdffit.fitting import physical
from brdffit.models.albedo import directional_albedo
from data_synth import make_table

pytestmark = pytest.mark.unit

REPORT_KEYS = {"unconstrained_log_rmse", "log_rmse", "relative_cost", "albedo_max_before",
               "albedo_max_before_theta_deg", "albedo_max_after", "albedo_max_after_theta_deg",
               "active", "scale", "unconstrained_params", "unconstrained_result"}
FAST = {"samples": 4096}


@pytest.mark.parametrize("name, params", [
    *[("ggx", {"kd": [0.2, 0.5, 0.0], "ks": [1, 0.5, 0.2], "alpha": a, "f0": 0.3})
      for a in (1e-3, 0.01, 0.1, 0.5, 1.5)],
    ("beckmann", {"kd": [0.2, 0.5, 0.0], "ks": [1, 0.5, 0.2], "alpha": 0.02, "f0": 1.0}),
    *[("blinn_phong", {"kd": [0.2, 0.5, 0.0], "ks": [1, 0.5, 0.2], "n": n}) for n in (1, 1e4)],
    ("gltf_pbr", {"base_color": [1, 0.9, 0.2], "metallic": 0.0, "roughness": 0.05}),
    ("gltf_pbr", {"base_color": [1, 0.9, 0.2], "metallic": 0.7, "roughness": 0.6}),
    ("rough_conductor", {"eta": [0.2, 0.9, 1.1], "k": [3.9, 2.4, 2.1], "alpha": 0.003,
                         "kd": [1, 1, 1], "weight": 0.3}),
    ("oren_nayar", {"kd": [1, 0.5, 0.2], "sigma": 0.5}),
    ("lambert", {"kd": [1, 0.5, 0.2]}),
])
def test_coarse_albedo_is_the_exact_one_to_within_its_margin(name, params):
    """The fit's cheap quadrature (1,792 half vectors) against brdffit.models.albedo's
    (131,072): within MARGIN where the albedo is largest, 1% at every incidence."""
    m = models.get(name)
    exact = directional_albedo(name, params)  # (incidences, 3)
    p = {k: jnp.asarray(v) for k, v in m.check_params(params).items()}
    coarse = np.asarray(physical.coarse_albedo(m, p, physical.albedo_grid("float64"))).T
    assert np.max(np.abs(coarse - exact)) < 0.01 * max(1.0, exact.max())
    assert abs(coarse.max() - exact.max()) < physical.MARGIN


def test_physical_ranges_bound_the_reflectances_only():
    ggx = {s.name: s.upper for s in models.get("ggx").physical_specs}
    assert ggx == {"kd": 1.0, "ks": 1.0, "alpha": 2.0, "f0": 1.0}
    ggx2 = {s.name: s.upper for s in models.get("ggx2").physical_specs}
    assert ggx2["ks1"] == ggx2["ks2"] == ggx2["kd"] == 1.0
    # already within [0, 1]: unchanged
    for name in ("gltf_pbr", "rough_conductor"):
        m = models.get(name)
        assert m.physical_specs == m.param_specs
    mono = models.get("ggx_mono").physical_specs
    assert [(s.name, s.rgb, s.upper) for s in mono][:2] == [("kd", True, 1.0), ("ks", False, 1.0)]
    # the bounded model is the same BRDF under its physical ranges
    bounded = physical.PhysicalRanges(models.get("ggx"))
    assert bounded.name == "ggx" and bounded.param_specs == models.get("ggx").physical_specs


def test_a_physical_material_is_fitted_as_it_is():
    table, _ = make_table("ggx", {"kd": [0.3, 0.2, 0.1], "ks": [0.5, 0.4, 0.3], "alpha": 0.2,
                                  "f0": 0.5})
    free = fit(table, "ggx", **FAST)
    bounded = fit(table, "ggx", physical=True, **FAST)
    assert free.physical is None
    assert bounded.params == free.params and bounded.error == free.error
    p = bounded.physical
    assert set(p) == REPORT_KEYS
    assert p["relative_cost"] == 0.0 and p["active"] == [] and p["scale"] == 1.0
    assert p["albedo_max_before"] == p["albedo_max_after"]


@pytest.mark.slow
def test_an_unphysical_fit_is_bounded_and_says_what_it_cost():
    # ks = 1.6 and a bright kd: the unconstrained fit reflects more than it receives
    table, _ = make_table("ggx", {"kd": [0.8, 0.7, 0.3], "ks": [1.6, 1.4, 1.0], "alpha": 0.3,
                                  "f0": 0.4})
    r = fit(table, "ggx", physical=True, **FAST)
    p = r.physical
    assert r.converged, r.result
    assert np.max(p["unconstrained_params"]["ks"]) > 1.2
    assert max(p["albedo_max_before"]) > 1.05
    albedo = directional_albedo("ggx", r.params)
    assert albedo.max() <= 1.0 and max(p["albedo_max_after"]) == pytest.approx(albedo.max())
    assert np.max(r.params["ks"]) <= 1.0 and np.max(r.params["kd"]) <= 1.0
    assert "range: ks[R] <= 1" in p["active"]
    assert any(a.startswith("energy: albedo[") for a in p["active"])
    assert p["log_rmse"] == r.error["log_rmse"] > p["unconstrained_log_rmse"]
    assert p["relative_cost"] == pytest.approx(p["log_rmse"] / p["unconstrained_log_rmse"] - 1)
    assert r.uncertainty is not None
    # its steps add up two solves, each under the limit: said, as the limit is per solve
    assert ("steps counts the bounded step's 2 barrier solves, each of at most 256; the "
            "result is the last one's") in r.notes


@pytest.mark.slow
def test_gltf_pbr_is_held_to_albedo_one_at_grazing():
    # glTF's formula reflects more than 1 towards grazing for a bright smooth dielectric
    # (docs/exports.md): the bounded fit gives up diffuse colour to conserve energy
    table, _ = make_table("gltf_pbr", {"base_color": [0.9, 0.8, 0.6], "metallic": 0.0,
                                       "roughness": 0.3})
    r = fit(table, "gltf_pbr", physical=True, **FAST)
    p = r.physical
    assert max(p["albedo_max_before"]) > 1.05 and p["albedo_max_before_theta_deg"] == 89
    assert directional_albedo("gltf_pbr", r.params).max() <= 1.0
    assert max(p["albedo_max_after"]) > 0.99  # held at the limit, not far below it
    assert any(a.startswith("energy: albedo[") for a in p["active"])
    assert 0 < p["relative_cost"] and r.converged, r.result


@pytest.mark.slow
def test_the_clamp_scales_the_linear_reflectances_to_albedo_one():
    ggx = {"kd": [0.9, 0.5, 0.2], "ks": [1.0, 0.9, 0.3], "alpha": 0.1, "f0": 0.5}
    m = models.get("ggx")
    clamped, scale, albedo = physical.energy_clamp(m, ggx)
    assert 0.5 < scale < 1 and albedo.max() <= 1.0 and albedo.max() == pytest.approx(1.0, abs=1e-6)
    np.testing.assert_allclose(clamped["kd"], np.multiply(ggx["kd"], scale))
    np.testing.assert_allclose(clamped["ks"], np.multiply(ggx["ks"], scale))
    assert clamped["alpha"] == ggx["alpha"] and clamped["f0"] == ggx["f0"]
    # glTF: quadratic in the base colour, a few steps, never above 1
    gltf = {"base_color": [1.0, 1.0, 0.9], "metallic": 0.0, "roughness": 0.2}
    clamped, scale, albedo = physical.energy_clamp(models.get("gltf_pbr"), gltf)
    assert scale < 1 and 0.99 < albedo.max() <= 1.0
    # a material within bounds is returned as it is
    ok = {"kd": [0.2, 0.2, 0.2], "ks": [0.2, 0.2, 0.2], "alpha": 0.1, "f0": 0.5}
    assert physical.energy_clamp(m, ok)[:2] == (ok, 1.0)


def test_the_barrier_is_finite_with_finite_slopes_down_to_a_black_channel():
    m = physical.PhysicalRanges(models.get("ggx"))
    grid = physical.albedo_grid("float64")
    u = jnp.asarray(m.unconstrain({"kd": [0.0, 0.3, 0.5], "ks": [0.0, 0.2, 0.4],
                                   "alpha": 0.2, "f0": 0.5}))
    # compiled, as the solver runs them: op by op, every primitive of the albedo and of
    # its Jacobian compiles on its own
    barrier = eqx.filter_jit(physical._barrier)
    r = barrier(u, m, grid, 1e-6)
    jac = eqx.filter_jit(jax.jacfwd(physical._barrier))(u, m, grid, 1e-6)
    assert np.all(np.isfinite(r)) and np.all(np.isfinite(jac))
    # outside the limit: infinite, so that the solver refuses the step
    out = jnp.asarray(m.unconstrain({"kd": [1.0, 1.0, 1.0], "ks": [1.0, 1.0, 1.0],
                                     "alpha": 0.2, "f0": 1.0}))
    assert np.all(np.isinf(barrier(out, m, grid, 1e-6)))


def test_bound_of_a_given_fit_is_the_physical_fit():
    table, _ = make_table("lambert", {"kd": [1.3, 0.4, 0.2]})
    free = fit(table, "lambert", **FAST)
    with jax.enable_x64(False):  # an entry point: in float64 whatever the caller's setting
        a = physical.bound(table, free, **FAST)
    b = fit(table, "lambert", physical=True, **FAST)
    assert a.params == b.params and a.physical == b.physical and a.error == b.error


def test_physical_fits_are_strict_json_and_read_back():
    table, _ = make_table("lambert", {"kd": [1.3, 0.4, 0.2]})
    r = fit(table, "lambert", physical=True, **FAST)
    text = r.to_json()
    assert "NaN" not in text and "Infinity" not in text
    back = FitResult.from_dict(json.loads(text))
    assert back.physical == json.loads(json.dumps(r.physical))
    assert np.max(r.params["kd"]) <= 1.0


def test_physical_must_be_a_bool():
    table, _ = make_table("lambert", {"kd": [0.3, 0.4, 0.2]})
    with pytest.raises(FitInputError, match="physical must be true or false"):
        fit(table, "lambert", physical="yes")


def test_the_service_estimate_counts_the_bounded_solves():
    from api.estimate import PHYSICAL_SOLVES, estimate
    from brdffit.request import FitRequest

    assert PHYSICAL_SOLVES == len(physical.BARRIERS)
    base = {"samples": 16384, "starts": 1, "max_steps": 256}
    assert (estimate(FitRequest.of("ggx", **base, physical=True), 10**6).seconds
            > estimate(FitRequest.of("ggx", **base), 10**6).seconds)
