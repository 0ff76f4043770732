"""The renderer target models gltf_pbr, rough_conductor and standard_surface: each against
its renderer's formula written independently, reciprocity, energy, NaN-free everywhere,
and recovery of their parameters from a table they made (standard_surface against
MaterialX's own shading: tests/test_materialx_shading.py)."""

from __future__ import annotations

import math

import jax.numpy as jnp
import numpy as np
import pytest

from brdffit import models
from brdffit.export.validate import gltf_spec_eval
from brdffit.fitting.pipeline import fit
from brdffit.io.merl import MerlTable
from brdffit.models.frame import shading_frame
from brdffit.models.microfacet import dielectric_fresnel
from brdffit.models.renderer_terms import conductor_fresnel
from tests.compiled_models import (
    assert_finite_transform_gradients,
    assert_finite_values_and_gradients,
    check_jit,
    evaluate,
)
from tests.test_models import _albedo, _jnp  # the same midpoint albedo and parameter cast

pytestmark = pytest.mark.unit

GLTF = {"base_color": [0.8, 0.35, 0.1], "metallic": 0.4, "roughness": 0.45}
CONDUCTOR = {"eta": [0.2, 0.9, 1.4], "k": [3.9, 2.4, 1.6], "alpha": 0.15,
             "kd": [0.3, 0.2, 0.1], "weight": 0.2}
PLASTIC = {"kd": [0.6, 0.25, 0.1], "alpha": 0.2, "eta": 1.5, "ks": [1.0, 0.9, 0.8]}
PRINCIPLED = {"base_color": [0.6, 0.25, 0.1], "roughness": 0.5, "specular": 0.5, "sheen": 0.4,
              "sheen_tint": 0.5}
CASES = {"gltf_pbr": GLTF, "gltf_pbr_ior": {**GLTF, "ior": 1.9}, "rough_conductor": CONDUCTOR,
         "rough_plastic": PLASTIC, "principled": PRINCIPLED}


def _pairs(n, seed=0):
    rng = np.random.default_rng(seed)
    v = rng.normal(size=(2, n, 3))
    v[..., 2] = np.abs(v[..., 2])
    v /= np.linalg.norm(v, axis=-1, keepdims=True)
    return v[0], v[1]


@check_jit  # one program: op by op, every primitive compiles on its own
def _pseudocode_channels(model, params, wi, wo):
    return model.pseudocode_channels(params, shading_frame(wi, wo))


def test_gltf_pbr_is_the_spec_brdf():
    wi, wo = _pairs(5000)
    keep = (wi[:, 2] > 1e-3) & (wo[:, 2] > 1e-3)
    wi, wo = wi[keep], wo[keep]
    for p in (GLTF, {"base_color": [1.0, 1.0, 1.0], "metallic": 1.0, "roughness": 0.04},
              {"base_color": [0.1, 0.5, 0.9], "metallic": 0.0, "roughness": 1.0}):
        for name, extra in (("gltf_pbr", {}), ("gltf_pbr_ior", {"ior": 1.5}),
                            ("gltf_pbr_ior", {"ior": 2.2})):
            q = {**p, **extra}
            model = models.get(name)
            ours = np.asarray(evaluate(model, _jnp(q), wi, wo))
            np.testing.assert_allclose(ours, gltf_spec_eval(q, wi, wo), rtol=1e-9, atol=1e-12)
            pseudo = np.moveaxis(np.asarray(
                _pseudocode_channels(model, _jnp(q), jnp.asarray(wi), jnp.asarray(wo))), 0, -1)
            np.testing.assert_allclose(pseudo, gltf_spec_eval(q, wi, wo, pseudocode=True),
                                       rtol=1e-9, atol=1e-12)


def test_gltf_definition_and_pseudocode_differ_only_in_the_diffuse_between_metal_and_not():
    """The two forms agree at metallic 0 and 1; between, the definition's diffuse is the
    larger (the pseudocode also dims it by the metal's Fresnel)."""
    wi, wo = _pairs(2000, seed=3)
    keep = (wi[:, 2] > 1e-3) & (wo[:, 2] > 1e-3)
    wi, wo = wi[keep], wo[keep]
    for m in (0.0, 1.0):
        q = {**GLTF, "metallic": m}
        np.testing.assert_allclose(gltf_spec_eval(q, wi, wo),
                                   gltf_spec_eval(q, wi, wo, pseudocode=True), rtol=1e-12)
    q = {"base_color": [0.9, 0.8, 0.7], "metallic": 0.73, "roughness": 0.2}
    spec = gltf_spec_eval(q, wi, wo)
    pseudo = gltf_spec_eval(q, wi, wo, pseudocode=True)
    assert np.all(spec >= pseudo - 1e-12)
    assert np.median(spec / pseudo) > 1.2


def test_conductor_fresnel_limits():
    c = jnp.linspace(0.0, 1.0, 101)
    # k = 0 is a dielectric: the exact dielectric Fresnel of microfacet.py
    for eta in (1.2, 1.5, 2.4):
        np.testing.assert_allclose(np.asarray(conductor_fresnel(eta, 0.0, c)),
                                   np.asarray(dielectric_fresnel(eta, c)), rtol=1e-9, atol=1e-12)
    # normal incidence: ((eta - 1)^2 + k^2) / ((eta + 1)^2 + k^2); grazing: 1
    for eta, k in ((0.2, 3.9), (1.66, 9.2), (3.1, 3.3)):
        f = np.asarray(conductor_fresnel(eta, k, jnp.array([1.0, 0.0])))
        assert f[0] == pytest.approx(((eta - 1) ** 2 + k**2) / ((eta + 1) ** 2 + k**2), rel=1e-12)
        assert f[1] == pytest.approx(1.0, rel=1e-12)


@pytest.mark.parametrize("name", list(CASES))
def test_reciprocity(name):
    wi, wo = _pairs(4000, seed=1)
    m, p = models.get(name), _jnp(CASES[name])
    a = np.asarray(m(p, jnp.asarray(wi), jnp.asarray(wo)))
    b = np.asarray(m(p, jnp.asarray(wo), jnp.asarray(wi)))
    np.testing.assert_allclose(a, b, rtol=1e-10, atol=1e-14)



@pytest.mark.parametrize("name, params, bound", [
    # glTF's (1 - F(v.h)) weighting of the diffuse is not exact energy conservation: a
    # white dielectric reflects up to ~10% more than it receives at 86 deg incidence (the
    # spec's own formula, which the model keeps; docs/models.md says so)
    ("gltf_pbr", {"base_color": [1.0, 1.0, 1.0], "metallic": 0.0, "roughness": 0.5}, 1.11),
    ("gltf_pbr", {"base_color": [1.0, 1.0, 1.0], "metallic": 1.0, "roughness": 0.3}, 1.0),
    ("rough_conductor", {"eta": [0.05] * 3, "k": [15.0] * 3, "alpha": 0.3, "kd": [1.0] * 3,
                         "weight": 0.0}, 1.0),
    ("rough_conductor", {"eta": [0.05] * 3, "k": [15.0] * 3, "alpha": 0.3, "kd": [1.0] * 3,
                         "weight": 0.5}, 1.0),
    # Mitsuba's roughplastic at its brightest: a white base under a smooth and a rough
    # interface (its internal reflectance is a 64-cosine mean, close to but not exactly
    # the integral: within 0.5%)
    ("rough_plastic", {"kd": [1.0] * 3, "alpha": 0.01, "eta": 1.5, "ks": [1.0] * 3}, 1.0),
    ("rough_plastic", {"kd": [1.0] * 3, "alpha": 0.8, "eta": 2.5, "ks": [1.0] * 3}, 1.0),
])
def test_energy_conservation_at_the_bounds(name, params, bound):
    model = models.get(name)
    for theta_i in (0.0, 0.6, 1.2, 1.5):
        a = _albedo(model, params, theta_i, n_theta=500, n_phi=500)
        assert np.all(a <= bound * 1.005) and np.all(a >= 0), (theta_i, a)


def _edge_directions():
    dirs = []
    for c in (0.0, 1e-6, 1e-3, 0.5, 1.0 - 1e-9, 1.0):
        s = math.sqrt(max(0.0, 1 - c * c))
        dirs += [[s * math.cos(p), s * math.sin(p), c] for p in (0.0, math.pi / 2, math.pi)]
    dirs = np.array(dirs)
    return jnp.asarray(np.repeat(dirs, len(dirs), 0)), jnp.asarray(np.tile(dirs, (len(dirs), 1)))


EDGES = {
    "gltf_pbr": [{"base_color": b, "metallic": m, "roughness": r}
                 for b in (0.0, 1.0) for m in (0.0, 1.0) for r in (math.sqrt(1e-3), 1.0)],
    "gltf_pbr_ior": [{"base_color": 0.5, "metallic": m, "roughness": r, "ior": i}
                     for m in (0.0, 1.0) for r in (math.sqrt(1e-3), 1.0) for i in (1.0, 3.0)],
    "rough_conductor": [{"eta": e, "k": k, "alpha": a, "kd": 0.5, "weight": w}
                        for e in (0.02, 1.0, 10.0) for k in (0.0, 15.0)
                        for a in (1e-3, 2.0) for w in (0.0, 1.0)],
    # each set evaluates the interface's ~0.5M quadrature points: the corners of alpha
    # and eta, with kd and ks at their ends in turn
    "rough_plastic": [{"kd": float(a > 1.0), "alpha": a, "eta": e, "ks": float(a < 1.0)}
                      for a in (1e-3, 2.0) for e in (1.001, 3.0)],
    "principled": [{"base_color": b, "roughness": r, "specular": s, "sheen": 1.0 - b,
                    "sheen_tint": t}
                   for b in (0.0, 1.0) for r in (math.sqrt(1e-3), 1.0) for s in (1e-3, 1.0)
                   for t in (0.0, 1.0)],
    "standard_surface_dielectric": [{"base_color": b, "specular_color": c,
                                     "specular_roughness": r, "specular_IOR": i}
                                    for b in (0.0, 1.0) for c in (0.0, 1.0)
                                    for r in (math.sqrt(1e-3), 1.0) for i in (1.0, 3.0)],
    "standard_surface": [{"base_color": b, "metalness": m, "specular_color": c,
                          "specular_roughness": r, "specular_IOR": i}
                         for b in (0.0, 1.0) for m in (0.0, 1.0) for c in (0.0, 1.0)
                         for r in (math.sqrt(1e-3), 1.0) for i in (1.0, 50.0)],
    "generalized_schlick": [{"kd": k, "color0": c0, "color90": c90, "exponent": e, "alpha": a}
                            for k in (0.0, 1.0) for c0, c90 in ((0.0, 1.0), (1.0, 0.0))
                            for e in (0.2, 20.0) for a in (1e-3, 1.0)],
}


@pytest.mark.parametrize("name", list(EDGES))
def test_finite_values_and_gradients_on_the_closed_hemisphere(name):
    m = models.get(name)
    wi, wo = _edge_directions()
    assert_finite_values_and_gradients(m, EDGES[name], wi, wo)
    u = jnp.asarray(m.unconstrain(m.check_params(EDGES[name][0])))
    assert_finite_transform_gradients(m, u, wi, wo)  # beyond both ends of every transform


def _table_of(name, params) -> MerlTable:
    from brdffit.export.conversion import fit_as_table
    from brdffit.fitting.result import FitResult

    return fit_as_table(FitResult(name, params, {}, True, "successful", 0, 0.0, {}))


def test_gltf_pbr_fit_recovers_its_parameters():
    r = fit(_table_of("gltf_pbr", GLTF), "gltf_pbr", samples=4096)
    assert r.converged and r.log_rmse < 1e-5
    for k, v in GLTF.items():
        np.testing.assert_allclose(r.params[k], v, rtol=1e-3, atol=1e-4)


def test_rough_conductor_fit_reproduces_its_table():
    # eta and k trade off against each other along the Fresnel curve, so the test is
    # on the BRDF (the error), and on alpha, the one parameter the data pins alone.
    r = fit(_table_of("rough_conductor", CONDUCTOR), "rough_conductor", samples=4096)
    assert r.log_rmse < 1e-4, r
    assert r.params["alpha"] == pytest.approx(CONDUCTOR["alpha"], rel=1e-2)


STANDARD = {"base_color": [0.6, 0.3, 0.1], "metalness": 0.3, "specular_color": [0.9, 0.8, 0.7],
            "specular_roughness": 0.4, "specular_IOR": 2.0}


def test_standard_surface_fit_reproduces_its_table():
    # metalness, base_color and specular_color share the colour between the metal, the
    # diffuse and the tint, so the test is on the BRDF and on the roughness
    r = fit(_table_of("standard_surface", STANDARD), "standard_surface", samples=4096)
    assert r.log_rmse < 1e-4, r
    assert r.params["specular_roughness"] == pytest.approx(0.4, rel=1e-2)


TINTED = {"kd": [0.3, 0.15, 0.08], "color0": [0.6, 0.3, 0.2], "color90": [0.3, 0.6, 0.7],
          "exponent": 1.5, "alpha": 0.15}


def test_generalized_schlick_fit_recovers_a_colour_that_turns():
    """A red lobe that turns blue-green away from normal incidence: recovered, the
    Fresnel's two colours and its exponent included."""
    r = fit(_table_of("generalized_schlick", TINTED), "generalized_schlick", samples=4096)
    assert r.converged and r.log_rmse < 1e-5, r
    for k, v in TINTED.items():
        np.testing.assert_allclose(r.params[k], v, rtol=1e-3, atol=1e-4, err_msg=k)


def test_standard_surface_layers_by_albedo_not_by_fresnel():
    """MaterialX's layer: the diffuse under the dielectric is weighted by the lobe's
    throughput 1 - E_spec(cos_o) comp(F(cos_d)), which the specular tint does not enter:
    a black tint still darkens the diffuse, alike in every channel."""
    m = models.get("standard_surface")
    wi, wo = _pairs(300, seed=4)
    p = {**STANDARD, "metalness": 0.0, "specular_color": [0.0, 0.0, 0.0]}
    f = np.asarray(evaluate(m, _jnp(p), wi, wo))  # one compiled program, not op by op
    base = np.asarray(STANDARD["base_color"]) / np.pi
    ratio = f / base
    assert np.all(ratio < 1.0) and np.all(ratio > 0.5)
    np.testing.assert_allclose(ratio[:, 0], ratio[:, 2], rtol=1e-12)
    metal = {**p, "metalness": 1.0, "specular_color": [1.0, 1.0, 1.0]}
    lobe = np.asarray(evaluate(m, _jnp(metal), wi, wo))
    f_black = np.asarray(evaluate(m, _jnp({**metal, "base_color": [0.0] * 3}), wi, wo))
    assert np.all(f_black >= 0) and np.all(lobe > f_black)


@pytest.mark.slow
def test_rough_plastic_fit_recovers_its_parameters():
    r = fit(_table_of("rough_plastic", PLASTIC), "rough_plastic", samples=4096)
    assert r.log_rmse < 1e-4, r
    assert r.params["alpha"] == pytest.approx(PLASTIC["alpha"], rel=1e-2)
    np.testing.assert_allclose(r.params["kd"], PLASTIC["kd"], rtol=2e-2)


def test_rough_plastic_transmittance_and_internal_reflectance_limits():
    """The interface's tables (Mitsuba's quadratures, brdffit.models.rough_plastic):
    at eta -> 1 a smooth interface vanishes (T = 1, nothing reflected inside); at normal
    incidence on a smooth interface T is 1 - F0; the internal reflectance of a smooth
    eta 1.5 interface is the known hemispherical 0.596 (1 - (1 - 0.0918) / eta^2), of
    which Mitsuba's mean over 64 cosines from 0 to 1 is 63/64."""
    from brdffit.models.rough_plastic import internal_reflectance, transmittance_table

    # cos >= 0.2, away from grazing's F = 1; smooth, for a rough interface also masks the
    # refracted light (Mitsuba's G1(wt, m): T 0.73 at cos 0.2 for alpha 0.3 and eta 1.001)
    t = np.asarray(transmittance_table(1e-3, 1.001))
    assert np.all(np.abs(t[13:] - 1.0) < 2e-4)
    assert np.all(np.asarray(transmittance_table(0.3, 1.001))[13:] < t[13:])
    smooth = np.asarray(transmittance_table(1e-3, 1.5))
    assert smooth[-1] == pytest.approx(1.0 - 0.04, abs=1e-4)
    assert float(internal_reflectance(1e-3, 1.001)) < 5e-3
    assert float(internal_reflectance(1e-3, 1.5)) == pytest.approx(0.596 * 63 / 64, abs=3e-3)


def test_standard_surface_dielectric_is_standard_surface_at_metalness_0():
    wi, wo = _pairs(500)
    p = {k: v for k, v in STANDARD.items() if k != "metalness"}
    ours = models.get("standard_surface_dielectric")(_jnp(p), jnp.asarray(wi), jnp.asarray(wo))
    core = models.get("standard_surface")(_jnp({**p, "metalness": 0.0}), jnp.asarray(wi),
                                          jnp.asarray(wo))
    np.testing.assert_allclose(np.asarray(ours), np.asarray(core), rtol=1e-12)


def test_auto_candidates_leave_the_target_models_out():
    from brdffit.selection import DEFAULT_CANDIDATES

    targets = {"gltf_pbr", "gltf_pbr_ior", "rough_conductor", "rough_plastic", "principled",
               "standard_surface", "standard_surface_dielectric"}
    assert not targets & set(DEFAULT_CANDIDATES)
    assert targets <= set(models.names())


def test_gltf_pbr_ior_contains_gltf_pbr():
    # seeded from a gltf_pbr fit (models.parent), the larger model never ends worse
    m = models.get("gltf_pbr_ior")
    assert m.parent == "gltf_pbr" and models.get("gltf_pbr").parent is None
    wi, wo = _pairs(500)
    ours = m(_jnp(m.embed_parent(GLTF)), jnp.asarray(wi), jnp.asarray(wo))
    core = models.get("gltf_pbr")(_jnp(GLTF), jnp.asarray(wi), jnp.asarray(wo))
    np.testing.assert_allclose(np.asarray(ours), np.asarray(core), rtol=1e-12)


def test_rough_plastic_interface_derivatives_are_autodiffs():
    """interface_terms' own JVP (two directions, then combined) is the derivative that
    autodiff of the quadratures gives."""
    import jax

    from brdffit.models.rough_plastic import (
        interface_terms,
        internal_reflectance,
        transmittance_table,
    )

    def direct(a, e):
        return transmittance_table(a, e), internal_reflectance(a, e)

    # compiled, not op by op
    ours_jvp = check_jit(lambda p, t: jax.jvp(interface_terms, p, t), comparison=True)
    theirs_jvp = check_jit(lambda p, t: jax.jvp(direct, p, t), comparison=True)
    for point, tangent in (((0.2, 1.5), (1.0, 0.0)), ((0.6, 2.1), (0.3, -0.7))):
        primals = tuple(jnp.asarray(x) for x in point)
        tangents = tuple(jnp.asarray(x) for x in tangent)
        ours = ours_jvp(primals, tangents)
        theirs = theirs_jvp(primals, tangents)
        for a, b in zip(jax.tree.leaves(ours), jax.tree.leaves(theirs), strict=True):
            np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=1e-10, atol=1e-14)
