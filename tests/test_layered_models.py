"""Layered materials (issue 40): a coat over glTF's base, ``gltf_clearcoat``, a sheen
over it, ``gltf_sheen``, a thin film, ``gltf_iridescence``, and Mitsuba's principled with
its coat.

Against the extension's text written independently in numpy
(``brdffit.export.validate.gltf_spec_eval``), NaN-free on the closed hemisphere, its
base exactly where the coat is off, recovered from a table it made, never worse than
its base on a table it did not make, and exported to glTF as the extension's factors.
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
import pytest

from brdffit import models
from brdffit.export import TARGETS, export
from brdffit.export import validate as check
from brdffit.export.gltf import CLEARCOAT_EXTENSION, IRIDESCENCE_EXTENSION, SHEEN_EXTENSION
from brdffit.export.validate import gltf_spec_eval
from brdffit.fitting.pipeline import fit
from brdffit.fitting.result import FitResult
from brdffit.fitting.sampling import DEFAULT_SAMPLES
from data_synth import make_table
from tests.compiled_models import assert_finite_values_and_gradients
from tests.test_export_tools import gltf_validator  # noqa: F401 - the fixture
from tests.test_models import _edge_directions, _jnp, _random_pairs
from tests.truths import assert_params_close

pytestmark = pytest.mark.unit

COATED = {"base_color": [0.45, 0.08, 0.05], "metallic": 0.7, "roughness": 0.55,
          "clearcoat": 0.9, "clearcoat_roughness": 0.1}


def _above(n, seed=0):
    wi, wo = _random_pairs(n, seed)
    keep = (wi[:, 2] > 1e-3) & (wo[:, 2] > 1e-3)
    return wi[keep], wo[keep]


def test_gltf_clearcoat_is_the_extension_brdf():
    """KHR_materials_clearcoat's coated material, term by term, for coats from off to
    full and from sharp to rough, on dielectric and metal bases."""
    _assert_spec("gltf_clearcoat", (
        COATED, {**COATED, "metallic": 0.0, "clearcoat": 0.3, "clearcoat_roughness": 1.0},
        {**COATED, "clearcoat": 1.0, "clearcoat_roughness": 0.0317},
        {**COATED, "clearcoat": 0.0}), seed=0)


def _assert_spec(name: str, param_sets, seed: int) -> None:
    """``name`` against ``validate.gltf_spec_eval`` (the extensions written in numpy,
    no code shared) at random pairs above the horizon, to 1e-9."""
    m = models.get(name)
    wi, wo = _above(5000, seed)
    for p in param_sets:
        ours = np.asarray(m(_jnp(p), jnp.asarray(wi), jnp.asarray(wo)))
        np.testing.assert_allclose(ours, gltf_spec_eval(p, wi, wo), rtol=1e-9, atol=1e-12)


@pytest.mark.parametrize("name", ["gltf_clearcoat", "gltf_sheen", "gltf_iridescence"])
def test_with_the_layer_off_it_is_its_base_exactly(name):
    m, base = models.get(name), models.get("gltf_pbr")
    assert m.parent == "gltf_pbr" and m.layers == (name.removeprefix("gltf_"),)
    wi, wo = _above(2000, seed=1)
    p = {"base_color": [0.45, 0.08, 0.05], "metallic": 0.7, "roughness": 0.55}
    layered = m(_jnp(m.embed_parent(p)), jnp.asarray(wi), jnp.asarray(wo))
    np.testing.assert_array_equal(np.asarray(layered),
                                  np.asarray(base(_jnp(p), jnp.asarray(wi), jnp.asarray(wo))))


STANDARD = {"base_color": [0.45, 0.08, 0.05], "metalness": 0.7,
            "specular_color": [0.9, 0.8, 0.7], "specular_roughness": 0.55, "specular_IOR": 1.5}
#: The viewers' and MaterialX's layered models, each over its parent's parameters.
TWINS = [("gltf_threejs_clearcoat", "gltf_threejs"), ("gltf_threejs_sheen", "gltf_threejs"),
         ("gltf_threejs_iridescence", "gltf_threejs"), ("gltf_blender_clearcoat", "gltf_blender"),
         ("gltf_blender_sheen", "gltf_blender"), ("standard_surface_coat", "standard_surface"),
         ("standard_surface_sheen", "standard_surface")]


@pytest.mark.parametrize(("name", "parent"), TWINS)
def test_a_renderers_layered_model_with_the_layer_off_is_its_parent_exactly(name, parent):
    m, base = models.get(name), models.get(parent)
    assert m.parent == parent
    wi, wo = _above(2000, seed=1)
    p = STANDARD if parent == "standard_surface" else {
        "base_color": [0.45, 0.08, 0.05], "metallic": 0.7, "roughness": 0.55}
    layered = m(_jnp(m.embed_parent(p)), jnp.asarray(wi), jnp.asarray(wo))
    np.testing.assert_array_equal(np.asarray(layered),
                                  np.asarray(base(_jnp(p), jnp.asarray(wi), jnp.asarray(wo))))


@pytest.mark.parametrize(("name", "parent"), TWINS)
def test_a_renderers_layered_model_is_finite_on_the_closed_hemisphere(name, parent):
    """Values and gradients at the parameters' bounds (a black base colour, whose film
    and metal reflectivity take square roots of 0, among them) and at grazing."""
    m = models.get(name)
    wi, wo = _edge_directions()
    edges = []
    for corner in (0.0, 1.0):
        p = {s.name: np.full(s.size, s.lower if corner == 0.0 else s.upper)
             for s in m.param_specs}
        edges.append({k: (v if len(v) > 1 else float(v[0])) for k, v in p.items()})
    edges.append({**m.embed_parent(STANDARD if parent == "standard_surface" else {
        "base_color": [0.0, 0.5, 1.0], "metallic": 0.5, "roughness": 0.0317})})
    assert_finite_values_and_gradients(m, edges, wi, wo)


def test_finite_values_and_gradients_on_the_closed_hemisphere():
    m = models.get("gltf_clearcoat")
    wi, wo = _edge_directions()
    edges = [{**COATED, "roughness": r, "clearcoat": c, "clearcoat_roughness": cr}
             for r in (0.0317, 1.0) for c in (0.0, 1.0) for cr in (0.0317, 1.0)]
    assert_finite_values_and_gradients(m, edges, wi, wo)


@pytest.mark.slow  # fits: the full suite runs them, the quick tier the formulas
def test_recovers_a_coat_from_a_table_it_made():
    table, _ = make_table("gltf_clearcoat", COATED, noise=0.01, seed=4)
    r = fit(table, "gltf_clearcoat", samples=8192)
    assert r.converged, r.result
    assert_params_close(r.params, COATED, rel=0.03, abs_small=0.01)


def _base_and_layered(table, name: str, samples: int):
    """gltf_pbr's fit of ``table`` and ``name``'s from it, the layered one never worse
    than its base (1.001x, as ggx2 against ggx)."""
    base = fit(table, "gltf_pbr", samples=samples)
    layered = fit(table, name, samples=samples, parent_fit=base)
    assert layered.error["log_rmse"] <= 1.001 * base.error["log_rmse"]
    return base, layered


@pytest.mark.slow  # fits: the full suite runs them, the quick tier the formulas
def test_never_worse_than_its_base_and_a_coat_where_there_is_one():
    """A sharp lobe over a broad one (ggx2's table, which no glTF model makes): the
    coat takes the sharp lobe; on the base's own table (with noise: on a noise-free one
    every residual is 0, and so is every standard error) it finds nothing to add, ends at
    the base's fit and says that the data show no coat."""
    two_lobes, _ = make_table("ggx2", {"kd": [0.05, 0.03, 0.02], "ks1": [0.08] * 3,
                                       "alpha1": 0.02, "ks2": [0.5, 0.2, 0.1], "alpha2": 0.4,
                                       "f0": 0.9})
    plain, _ = make_table("gltf_pbr", {"base_color": [0.5, 0.3, 0.2], "metallic": 0.2,
                                       "roughness": 0.5}, noise=0.01, seed=2)
    for table, gains in ((two_lobes, True), (plain, False)):
        base, coated = _base_and_layered(table, "gltf_clearcoat", samples=4096)
        seen = coated.uncertainty["layers"]["clearcoat"]
        if gains:
            assert coated.error["log_rmse"] < 0.7 * base.error["log_rmse"]
            assert coated.params["clearcoat"] > 0.2
            assert coated.params["clearcoat_roughness"] < coated.params["roughness"]
            assert seen["status"] == "identified", seen
        else:  # a coat of ~0 says so, and its roughness is not claimed
            assert seen["status"] == "absent", seen
            assert coated.uncertainty["why"]["clearcoat_roughness"].startswith("no layer")


@pytest.mark.slow  # fits: the full suite runs them, the quick tier the formulas
def test_a_layer_worse_than_its_base_on_the_table_is_put_back_at_the_base():
    """The promise is on the whole table, not only the solver's samples: a layered
    optimum whose table log_rmse is above 1.001x its base's is replaced by the base's
    optimum with the layer off, refined, and the notes say so. (A base that claims a
    thousandth of its real error stands in for a layer that fitted the samples' noise.)"""
    import dataclasses

    table, _ = make_table("gltf_pbr", {"base_color": [0.5, 0.3, 0.2], "metallic": 0.2,
                                       "roughness": 0.5}, noise=0.01, seed=2)
    base = fit(table, "gltf_pbr", samples=4096)
    coated = fit(table, "gltf_clearcoat", samples=4096, parent_fit=base)
    assert not any("worse than gltf_pbr's" in n for n in coated.notes)
    flattering = dataclasses.replace(
        base, error={**base.error, "log_rmse": 1e-3 * base.error["log_rmse"]})
    back = fit(table, "gltf_clearcoat", samples=4096, parent_fit=flattering)
    assert any("optimum on the samples was worse than gltf_pbr's on the table" in n
               for n in back.notes), back.notes
    assert back.params["clearcoat"] < 1e-3  # the base's optimum, the coat off
    assert back.error["log_rmse"] == pytest.approx(base.error["log_rmse"], rel=1e-3)


@pytest.mark.slow  # the glTF validator: the quick tier keeps the formulas
def test_a_coated_fit_exports_to_gltf_as_the_extension(gltf_validator):  # noqa: F811
    table, _ = make_table("gltf_clearcoat", COATED)
    # the truth as the fit (a coat is recovered by the tests above): the export is checked
    r = FitResult("gltf_clearcoat", COATED, {"log_rmse": 0.01}, True, "successful", 5, 0.1, {})
    e = export(r, "gltf", table=table)
    report = check.gltf_validate(e.material, gltf_validator)  # the Khronos validator
    assert report["issues"]["numErrors"] == 0 and report["issues"]["numWarnings"] == 0, report
    assert e.fidelity["exact"] and e.fidelity["log_rmse_to_fit"] == 0.0
    (material,) = e.material["materials"]
    coat = material["extensions"][CLEARCOAT_EXTENSION]
    assert coat == {"clearcoatFactor": pytest.approx(r.params["clearcoat"]),
                    "clearcoatRoughnessFactor": pytest.approx(r.params["clearcoat_roughness"])}
    assert CLEARCOAT_EXTENSION in e.material["extensionsUsed"]
    assert any("KHR_materials_clearcoat" in w for w in e.warnings)
    # the file's factors, shaded as the extension says, are the fit
    wi, wo = _above(2000, seed=2)
    m = models.get("gltf_clearcoat")
    np.testing.assert_allclose(gltf_spec_eval(e.target_params, wi, wo),
                               np.asarray(m(_jnp(r.params), jnp.asarray(wi), jnp.asarray(wo))),
                               rtol=1e-6)
    # three.js's and Blender's coats are their own models (tests/test_export_viewers.py,
    # tests/test_export_blender.py)
    assert e.fidelity["viewers"]["threejs"]["model"] == "gltf_threejs_clearcoat"
    assert e.fidelity["viewers"]["blender"]["model"] == "gltf_blender_clearcoat"


# -- Mitsuba's principled with its clearcoat ---------------------------------------------

PRINCIPLED_COATED = {"base_color": [0.3, 0.05, 0.04], "roughness": 0.6, "specular": 0.5,
                     "sheen": 0.0, "sheen_tint": 0.0, "clearcoat": 0.8, "clearcoat_gloss": 0.8}


@pytest.mark.parametrize("params", [
    PRINCIPLED_COATED,
    {"base_color": [0.7, 0.3, 0.1], "roughness": 0.4, "specular": 0.5, "sheen": 0.5,
     "sheen_tint": 0.6, "clearcoat": 0.8, "clearcoat_gloss": 0.7},
    {"base_color": [0.1, 0.4, 0.9], "roughness": 0.9, "specular": 0.9, "sheen": 0.0,
     "sheen_tint": 0.0, "clearcoat": 1.0, "clearcoat_gloss": 0.0},
    {"base_color": [0.2, 0.2, 0.2], "roughness": 0.6, "specular": 0.2, "sheen": 0.0,
     "sheen_tint": 0.0, "clearcoat": 0.3, "clearcoat_gloss": 1.0}])
def test_principled_clearcoat_is_mitsubas_own(params):
    """Against Mitsuba's ``BSDF.eval`` of the exported dictionary, at random pairs. Within
    a thousandth of a radian of the mirror, Mitsuba's float32 ``1 + (a^2 - 1) cos_h^2``
    of its sharpest coat (gloss 1, a = 0.001) cancels: the same formula in numpy float32
    is 4e-4 off float64 there, and so is Mitsuba."""
    from brdffit.export import mitsuba

    material = mitsuba.load_dict(params)
    assert material["clearcoat"] == params["clearcoat"]
    rng = np.random.default_rng(2)
    v = rng.normal(size=(2, 3000, 3))
    v[..., 2] = np.abs(v[..., 2]) + 1e-3
    wi, wo = v / np.linalg.norm(v, axis=-1, keepdims=True)
    m = models.get("principled_clearcoat")
    ours = np.asarray(m(_jnp(m.check_params(params)), jnp.asarray(wi), jnp.asarray(wo)))
    theirs = check.mitsuba_eval(material, wi, wo)
    h = wi + wo
    cos_h = h[:, 2] / np.linalg.norm(h, axis=-1)
    far = 1.0 - cos_h > 1e-3
    np.testing.assert_allclose(theirs[far], ours[far], rtol=5e-5)  # Mitsuba's float32
    np.testing.assert_allclose(theirs[~far], ours[~far], rtol=2e-3)


@pytest.mark.slow  # fits: the full suite runs them, the quick tier the formulas
def test_principled_clearcoat_starts_from_principled_and_finds_a_coat():
    m = models.get("principled_clearcoat")
    assert m.parent == "principled"
    wi, wo = _above(1000, seed=3)
    p = {k: v for k, v in PRINCIPLED_COATED.items() if not k.startswith("clearcoat")}
    np.testing.assert_array_equal(
        np.asarray(m(_jnp(m.embed_parent(p)), jnp.asarray(wi), jnp.asarray(wo))),
        np.asarray(models.get("principled")(_jnp(p), jnp.asarray(wi), jnp.asarray(wo))))
    assert_finite_values_and_gradients(m, [
        {**PRINCIPLED_COATED, "roughness": r, "clearcoat": c, "clearcoat_gloss": g}
        for r in (0.0317, 1.0) for c in (0.0, 1.0) for g in (0.0, 1.0)], *_edge_directions())
    table, _ = make_table("principled_clearcoat", PRINCIPLED_COATED, noise=0.01, seed=5)
    base = fit(table, "principled", samples=8192)
    coated = fit(table, "principled_clearcoat", samples=8192, parent_fit=base)
    assert coated.converged, coated.result
    assert coated.error["log_rmse"] < 0.5 * base.error["log_rmse"]
    assert_params_close(coated.params, PRINCIPLED_COATED, rel=0.05, abs_small=0.02)


# -- glTF's base under a sheen (KHR_materials_sheen) --------------------------------------

SHEENED = {"base_color": [0.25, 0.04, 0.06], "metallic": 0.0, "roughness": 0.8,
           "sheen_color": [0.8, 0.35, 0.4], "sheen_roughness": 0.45}


def test_gltf_sheen_is_the_extension_layering_of_threejs_sheen():
    """KHR_materials_sheen's layering (``f_sheen + material * sheenAlbedoScaling``) of
    three.js's sheen BRDF, against its GLSL transcribed in numpy, for sheens from off to
    full and from sharp to broad, over dielectric and metal bases."""
    _assert_spec("gltf_sheen", (
        SHEENED, {**SHEENED, "metallic": 1.0, "sheen_roughness": 1.0},
        {**SHEENED, "sheen_color": [1.0, 1.0, 1.0], "sheen_roughness": 0.1},
        {**SHEENED, "sheen_color": [0.0, 0.0, 0.0]}), seed=5)


def test_the_sheen_is_finite_on_the_closed_hemisphere():
    m = models.get("gltf_sheen")
    edges = [{**SHEENED, "roughness": r, "sheen_color": [c] * 3, "sheen_roughness": sr}
             for r in (0.0317, 1.0) for c in (0.0, 1.0) for sr in (0.1, 1.0)]
    assert_finite_values_and_gradients(m, edges, *_edge_directions())


@pytest.mark.slow  # fits: the full suite runs them, the quick tier the formulas
def test_a_sheen_is_found_where_there_is_one_and_never_costs_the_base():
    """On a velvet it made, the sheen is recovered from the base's fit; on the base's
    own table it finds nothing to add and ends at the base's fit."""
    velvet, _ = make_table("gltf_sheen", SHEENED, noise=0.01, seed=7)
    plain, _ = make_table("gltf_pbr", {"base_color": [0.5, 0.3, 0.2], "metallic": 0.2,
                                       "roughness": 0.5})
    for table, gains in ((velvet, True), (plain, False)):
        base, sheened = _base_and_layered(table, "gltf_sheen", samples=8192)
        if gains:
            assert sheened.converged, sheened.result
            assert sheened.error["log_rmse"] < 0.5 * base.error["log_rmse"]
            assert_params_close(sheened.params, SHEENED, rel=0.05, abs_small=0.02)


def test_a_sheened_fit_exports_to_gltf_as_the_extension(gltf_validator):  # noqa: F811
    r = FitResult("gltf_sheen", SHEENED, {"log_rmse": 0.01}, True, "successful", 5, 0.1, {})
    e = export(r, "gltf")
    report = check.gltf_validate(e.material, gltf_validator)  # the Khronos validator
    assert report["issues"]["numErrors"] == 0 and report["issues"]["numWarnings"] == 0, report
    # the fit's own factors, in a file whose sheen each viewer shades its own way (the
    # extension leaves the BRDF to them): not exact, and nothing lost in the conversion
    assert not e.fidelity["exact"] and e.fidelity["log_rmse_to_fit"] == 0.0
    (material,) = e.material["materials"]
    assert material["extensions"][SHEEN_EXTENSION] == {
        "sheenColorFactor": pytest.approx(SHEENED["sheen_color"]),
        "sheenRoughnessFactor": pytest.approx(SHEENED["sheen_roughness"])}
    assert SHEEN_EXTENSION in e.material["extensionsUsed"]
    assert any(SHEEN_EXTENSION in w for w in e.warnings)


# -- glTF's base under a thin film (KHR_materials_iridescence) ----------------------------

FILMED = {"base_color": [0.5, 0.5, 0.5], "metallic": 1.0, "roughness": 0.3,
          "iridescence": 1.0, "iridescence_ior": 1.5, "iridescence_thickness": 400.0}
#: A weak film over a dark, mostly dielectric base: one start ends in another cycle of
#: the film's hue (log_rmse 4.7x the truth's)
FAINT_FILM = {"base_color": [0.1, 0.1, 0.12], "metallic": 0.2, "roughness": 0.35,
              "iridescence": 0.9, "iridescence_ior": 1.8, "iridescence_thickness": 500.0}


def test_gltf_iridescence_is_the_extension_brdf():
    """KHR_materials_iridescence's conductor and dielectric layers, term by term, for
    films from off to full, thin to thick, low to high index, on metal, dielectric and
    mixed bases; a base colour of 1 (the text's own guard would fail there)."""
    _assert_spec("gltf_iridescence", (
        FILMED, FAINT_FILM,
        {**FILMED, "metallic": 0.0, "base_color": [0.2, 0.5, 0.9], "roughness": 0.0317,
         "iridescence_ior": 2.5, "iridescence_thickness": 1200.0},
        {**FILMED, "base_color": [1.0, 0.9, 0.0], "iridescence": 0.3,
         "iridescence_ior": 1.2, "iridescence_thickness": 30.0},
        {**FILMED, "iridescence": 0.0}), seed=6)


def test_the_film_tints_the_highlight_with_its_angle():
    """What a film is for: the highlight's hue turns with the angle (a grey metal's
    red-to-blue ratio changes by more than 20% from the normal to 60 degrees), and
    without the film it stays grey."""
    m = models.get("gltf_iridescence")

    def mirror_colour(p, theta):
        wi = np.array([[np.sin(theta), 0.0, np.cos(theta)]])
        wo = np.array([[-np.sin(theta), 0.0, np.cos(theta)]])
        return np.asarray(m(_jnp(p), jnp.asarray(wi), jnp.asarray(wo)))[0]

    for p, turns in ((FILMED, True), ({**FILMED, "iridescence": 0.0}, False)):
        ratios = [c[0] / c[2] for c in (mirror_colour(p, t) for t in (0.0, np.radians(60)))]
        assert bool(abs(ratios[1] / ratios[0] - 1) > 0.2) is turns, ratios


def test_the_film_is_finite_on_the_closed_hemisphere():
    m = models.get("gltf_iridescence")
    edges = [{**FILMED, "roughness": r, "metallic": mt, "iridescence": f,
              "iridescence_ior": n, "iridescence_thickness": d, "base_color": [c] * 3}
             for r in (0.0317, 1.0) for mt in (0.0, 1.0) for f in (0.0, 1.0)
             for n, d in ((1.2, 30.0), (2.5, 1200.0)) for c in (0.0, 1.0)]
    assert_finite_values_and_gradients(m, edges, *_edge_directions())


@pytest.mark.slow  # fits: the full suite runs them, the quick tier the formulas
# with test_quality.py's film truth on one worker, at its default samples: the film's
# programs compile once (~100 s of a fresh clone's run, each, when they were apart)
@pytest.mark.xdist_group("gltf_iridescence")
def test_a_film_is_found_in_its_cycle_and_never_costs_the_base():
    """On a table it made, a weak film over a dark base is recovered from the base's
    fit (the scan over the base's fit and the four starts: one start ended a hue cycle
    away); on the base's own table it finds nothing to add. (A strong film over a metal
    is recovered exactly by tests/test_quality.py's truth.)"""
    # noisy: on a noise-free table both fit to ~1e-8, where 1.001x means nothing
    plain, _ = make_table("gltf_pbr", {"base_color": [0.5, 0.3, 0.2], "metallic": 0.2,
                                       "roughness": 0.5}, noise=0.01, seed=2)
    for params, seed in ((FAINT_FILM, 3),):
        table, _ = make_table("gltf_iridescence", params, noise=0.01, seed=seed)
        base, filmed = _base_and_layered(table, "gltf_iridescence", samples=DEFAULT_SAMPLES)
        assert filmed.converged, filmed.result
        assert filmed.error["log_rmse"] < 0.3 * base.error["log_rmse"]
        assert_params_close(filmed.params, params, rel=0.03, abs_small=0.02)
        assert filmed.starts >= 4 and "4 starts refined (1 asked)" in filmed.notes[0]
        assert filmed.uncertainty["layers"]["iridescence"]["status"] == "identified"
    _, filmed = _base_and_layered(plain, "gltf_iridescence", samples=DEFAULT_SAMPLES)
    assert filmed.uncertainty["layers"]["iridescence"]["status"] == "absent"
    # the absent film's thickness and index are held while its weight is at 0, so the
    # fit ends optimal (free, they kept every start crawling to the step limit)
    assert filmed.converged, (filmed.result, filmed.steps)


def test_an_absent_films_shape_is_held_by_the_solver_and_a_coats_is_not():
    from brdffit.models.base import HELD

    film = models.get("gltf_iridescence")
    u = film.unconstrain(film.check_params(FAINT_FILM))
    names = [s.name for s in film.param_specs for _ in range(s.size)]
    shape = [i for i, n in enumerate(names) if n in ("iridescence_ior", "iridescence_thickness")]
    weight = names.index("iridescence")
    assert not np.any(np.asarray(film.solver_bound_side(jnp.asarray(u))) >= HELD)
    off = jnp.asarray(u).at[weight].set(-14.0)  # a film of 1e-6: in its lower tail
    side = np.asarray(film.solver_bound_side(off))
    assert np.all(side[shape] == HELD + weight) and side[weight] == -1
    np.testing.assert_array_equal(np.asarray(film.bound_side(off))[shape], 0)  # as reported
    coat = models.get("gltf_clearcoat")  # not opted in: its roughness stays free
    cu = jnp.full(sum(s.size for s in coat.param_specs), -14.0)
    assert not np.any(np.asarray(coat.solver_bound_side(cu)) >= HELD)


@pytest.mark.slow  # a film's fit and the glTF validator: ~10 s
def test_a_filmed_fit_exports_to_gltf_as_the_extension(gltf_validator):  # noqa: F811
    table, _ = make_table("gltf_iridescence", FILMED)
    r = FitResult("gltf_iridescence", FILMED, {"log_rmse": 0.01}, True, "successful", 5,
                  0.1, {})
    e = export(r, "gltf", table=table)
    report = check.gltf_validate(e.material, gltf_validator)  # the Khronos validator
    assert report["issues"]["numErrors"] == 0 and report["issues"]["numWarnings"] == 0, report
    assert e.fidelity["exact"]
    (material,) = e.material["materials"]
    assert material["extensions"][IRIDESCENCE_EXTENSION] == {
        "iridescenceFactor": 1.0, "iridescenceIor": 1.5,
        "iridescenceThicknessMinimum": 400.0, "iridescenceThicknessMaximum": 400.0}
    assert IRIDESCENCE_EXTENSION in e.material["extensionsUsed"]
    assert any(IRIDESCENCE_EXTENSION in w for w in e.warnings)
    # three.js's film is its own model (tests/test_export_viewers.py); Blender reads no
    # film: it shades the base (tests/test_export_blender.py)
    assert e.fidelity["viewers"]["threejs"]["model"] == "gltf_threejs_iridescence"
    assert e.fidelity["viewers"]["blender"]["ignores"] == [
        "iridescence", "iridescence_ior", "iridescence_thickness"]


# -- auto chooses the layers ---------------------------------------------------------------


@pytest.mark.slow  # fits: the full suite runs them, the quick tier the formulas
@pytest.mark.parametrize(("model", "params", "layered", "weight", "layer", "gain"), [
    ("gltf_clearcoat", COATED, "standard_surface_coat", "coat", "clearcoat", 0.5),
    ("gltf_sheen", SHEENED, "standard_surface_sheen", "sheen", "sheen", 0.7)])
def test_a_layered_fit_exports_to_materialx_with_its_layer(model, params, layered, weight,
                                                           layer, gain):
    """MaterialX's standard_surface has a coat and a sheen: a coat or sheen fit is
    refitted as standard_surface_coat or _sheen (the layer kept, no layer warning),
    closer to the fit than the plain node, which says the layer was lost."""
    table, _ = make_table(model, params)
    # the truth as the fit (the layers are recovered by the tests above)
    r = FitResult(model, params, {"log_rmse": 0.01}, True, "successful", 5, 0.1, {})
    e = export(r, "materialx", table=table)
    assert e.fidelity["target_model"] == layered
    assert e.target_params[weight] > 0.2
    assert f'<input name="{weight}" type="float"' in e.material
    assert not any(w.startswith("layer:") for w in e.warnings), e.warnings
    plain = export(r, "materialx", table=table, target_model="standard_surface")
    assert e.fidelity["log_rmse_to_fit"] < gain * plain.fidelity["log_rmse_to_fit"], (
        e.fidelity["log_rmse_to_fit"], plain.fidelity["log_rmse_to_fit"])
    assert any(w.startswith(f"layer: the {layer} of the {model} fit")
               for w in plain.warnings), plain.warnings


def test_a_renderers_name_stands_for_its_materials_layers_included():
    from brdffit.fitting.options import SelectionRule
    from brdffit.models.catalogue import CANDIDATE_SETS

    assert SelectionRule(candidates=("gltf",)).candidates == (
        "gltf_pbr", "gltf_clearcoat", "gltf_sheen")
    assert SelectionRule(candidates=("ggx", "gltf", "gltf_pbr")).candidates == (
        "ggx", "gltf_pbr", "gltf_clearcoat", "gltf_sheen")
    for name, members in CANDIDATE_SETS.items():  # each a registry model, base first
        assert all(models.get(m).parent in (None, *members[:i])
                   for i, m in enumerate(members)), name
        # ... and one its renderer's export copies exactly: auto's choice is the file
        assert set(members) <= set(TARGETS[name].target_models), name
    assert "lambert" in CANDIDATE_SETS["mitsuba"]  # its diffuse: a matte table's cheapest
    with pytest.raises(Exception, match="unknown model 'gltf2'"):
        SelectionRule(candidates=("gltf2",))


def test_default_stands_for_autos_own_list_and_more_lobes_join_it():
    from brdffit.fitting.options import SelectionRule
    from brdffit.models.catalogue import auto_candidates

    rule = SelectionRule(candidates=("default", "ggx3", "ggx4"))
    assert rule.candidates == (*auto_candidates(), "ggx3", "ggx4")
    assert "ggx3" not in auto_candidates() and "ggx2" in auto_candidates()
    # beside a renderer's set, and named twice: each model once, in the order given
    assert SelectionRule(candidates=("ggx", "default", "gltf")).candidates == (
        "ggx", *[m for m in auto_candidates() if m != "ggx"],
        "gltf_pbr", "gltf_clearcoat", "gltf_sheen")


@pytest.mark.slow  # fits: the full suite runs them, the quick tier the formulas
def test_auto_takes_a_sheen_where_it_is_seen_and_not_where_it_is_not():
    """auto among glTF's materials on a velvet: the sheen wins, and the ranking says
    what each layer bought over the base; in a scene whose lights and views stay within
    30 degrees of the normal, where the fibres show nothing, the base is enough."""
    from brdffit.fitting.scene import Scene
    from brdffit.selection import format_selection, select

    velvet, _ = make_table("gltf_sheen", SHEENED, noise=0.01, seed=8)
    sel = select(velvet, ("gltf",), samples=8192)
    assert sel.chosen == "gltf_sheen", sel.reason
    rows = {row["model"]: row for row in sel.ranking}
    gain = rows["gltf_sheen"]["over_parent"]
    assert gain["model"] == "gltf_pbr" and gain["log_rmse_ratio"] < 0.5
    assert gain["psnr_gain_db"] > 1.0
    assert rows["gltf_clearcoat"]["over_parent"]["model"] == "gltf_pbr"
    assert "over_parent" not in rows["gltf_pbr"]
    assert "gltf_sheen over gltf_pbr log_rmse x" in format_selection(sel)
    near_normal = Scene(max_theta_i=30.0, max_theta_o=30.0)
    assert select(velvet, ("gltf",), scene=near_normal, samples=8192).chosen == "gltf_pbr"


def test_each_layer_says_whether_the_data_determine_it():
    """The uncertainty's per-layer summary, from its parameters' own verdicts: a weight
    within its error of 0 is an absent layer; a layer that is there but has a parameter
    the data do not fix is unresolved, with that parameter's reason; else identified."""
    from brdffit.fitting.uncertainty import _layers

    m = models.get("principled_clearcoat")
    names = ["base_color[0]", "base_color[1]", "base_color[2]", "roughness", "specular",
             "sheen", "sheen_tint", "clearcoat", "clearcoat_gloss"]
    reasons = [None] * 6 + ["no layer: sheen within 2 standard errors of 0", None,
                            "loose: standard error 0.4 against a scale of 0.5"]
    layers = _layers(m, names, reasons, significant=lambda scales: scales != ("sheen",))
    assert layers["sheen"] == {"status": "absent", "why": "sheen within 2 standard errors "
                               "of 0: the data show no sheen"}
    assert layers["clearcoat"] == {"status": "unresolved", "why": "clearcoat_gloss: loose: "
                                   "standard error 0.4 against a scale of 0.5"}
    reasons[-1] = None
    assert _layers(m, names, reasons, lambda s: True)["clearcoat"]["status"] == "identified"
    # determined one by one, yet the data tell them apart only together: said
    tied = _layers(m, names, reasons, lambda s: True,
                   {"clearcoat": ["clearcoat_gloss", "roughness"],
                    "clearcoat_gloss": ["clearcoat"]})["clearcoat"]
    assert tied["status"] == "identified" and tied["why"].endswith(
        "; clearcoat, clearcoat_gloss correlate beyond 0.95: the data tell them apart only "
        "together")
    # a shape at its bound is not "determined" alone: the data would take it further
    # (a weight at its bound is a full layer, which says nothing of the kind)
    held = _layers(m, names, reasons, lambda s: True,
                   bounded=["clearcoat", "clearcoat_gloss"])["clearcoat"]
    assert held["status"] == "identified" and held["why"] == (
        "clearcoat, clearcoat_gloss each determined by the data; clearcoat_gloss at the model's "
        "bound: the data would take it further")
    assert _layers(models.get("ggx"), ["kd[0]"], [None], lambda s: True) == {}


def test_an_export_without_the_layer_says_what_was_lost():
    """A layer the target's model lacks is named with the refit's log_rmse to the fit
    (MaterialX's standard_surface here has no sheen; Mitsuba's principled has Burley's,
    so a sheen exported there is not called lost)."""
    from brdffit.export import TARGETS, _layer_warning
    from brdffit.export.conversion import Conversion

    materialx, mitsuba, gltf = (TARGETS[t] for t in ("materialx", "mitsuba", "gltf"))
    (lost,) = _layer_warning("gltf_sheen", Conversion("standard_surface", {}, False, 0.0239),
                             materialx)
    assert lost.startswith("layer: the sheen of the gltf_sheen fit has no counterpart in "
                           "standard_surface") and "log_rmse 0.0239 to the fit" in lost
    # the target's model that keeps it is named (the warning read as if the renderer
    # had no such layer)
    assert lost.endswith("; standard_surface_sheen keeps it: export with target_model "
                         "standard_surface_sheen (brdffit export --target-model "
                         "standard_surface_sheen)")
    (coat,) = _layer_warning("principled_clearcoat", Conversion("principled", {}, False, 0.01),
                             mitsuba)
    assert "the clearcoat of the principled_clearcoat fit" in coat
    assert "principled_clearcoat keeps it" in coat
    (film,) = _layer_warning("gltf_iridescence", Conversion("standard_surface", {}, False,
                                                            0.01), materialx)
    assert "keeps it" not in film  # MaterialX's models here have no thin film
    assert _layer_warning("gltf_sheen", Conversion("principled", {}, False, 0.02),
                          mitsuba) == []
    assert _layer_warning("gltf_clearcoat", Conversion("gltf_clearcoat", {}, True, 0.0),
                          gltf) == []
    assert _layer_warning("ggx", Conversion("gltf_pbr", {}, False, 0.01), gltf) == []


def _log_rule(rows):
    from brdffit.selection import choose

    return choose(rows, 0.005, by_look=False)[0]


def test_a_layer_that_renders_worse_than_its_base_is_not_chosen():
    """Under the log loss a layer can buy log_rmse at grazing bins and cost the look:
    the rule's choice falls back to the choice without a layer where the layer renders
    more than 0.5 dB worse than its base, and says so; a second lobe (ggx2 over ggx)
    is no layer and stays."""
    from brdffit.selection import _layer_gains, _layer_no_worse_than_without

    rows = [{"model": "gltf_pbr", "log_rmse": 0.02, "psnr_db": 30.0, "n_params": 8},
            {"model": "gltf_sheen", "log_rmse": 0.015, "psnr_db": 25.0, "n_params": 12},
            {"model": "ggx", "log_rmse": 0.03, "psnr_db": 30.0, "n_params": 8},
            {"model": "ggx2", "log_rmse": 0.012, "psnr_db": 28.0, "n_params": 12}]
    _layer_gains(rows)
    assert rows[1]["over_parent"] == {"model": "gltf_pbr", "log_rmse_ratio": 0.75,
                                      "psnr_gain_db": -5.0, "no_gain": False}

    def guard(chosen):
        return _layer_no_worse_than_without(chosen, "Chose it.", rows, "log_rmse", _log_rule)

    chosen, reason = guard(rows[1])
    assert chosen is rows[3]  # the choice without a layer, not the sheen's own base
    assert "gltf_sheen passes the rule but renders 5.0 dB worse than its base gltf_pbr" \
        in reason and reason.endswith(
            "so ggx2, the choice without a layer (log_rmse 0.012, 28.0 dB, None), is chosen.")
    assert guard(rows[3]) == (rows[3], "Chose it.")
    rows[1]["over_parent"]["psnr_gain_db"] = -0.4  # within the slack
    rows[1]["psnr_db"] = 29.6
    rows[1]["log_rmse"] = 0.012  # as close as ggx2: the layer stays
    assert guard(rows[1]) == (rows[1], "Chose it.")


def test_under_the_log_rule_a_layer_is_no_further_off_than_the_choice_without_one():
    """A cheaper layered model within the tolerance replaced a closer fit without a
    layer (black-oxidized-steel under the log loss: gltf_clearcoat, 9 values, over
    generalized_schlick, 11, at a higher log_rmse). A layered choice must be within
    1.001x of the log_rmse of the choice without a layer, and render no more than
    0.5 dB worse; the reason says which it missed."""
    from brdffit.selection import _layer_gains, _layer_no_worse_than_without, choose

    def rows(coat_log_rmse, coat_db):
        return [{"model": m, "log_rmse": e, "psnr_db": db, "n_params": n, "verdict": "good",
                 "radiance_verdict": "good"}
                for m, e, db, n in (("gltf_pbr", 0.0104, 24.0, 8),
                                    ("gltf_clearcoat", coat_log_rmse, coat_db, 9),
                                    ("generalized_schlick", 0.0082, 24.5, 11))]

    ok = rows(0.0090, 24.4)
    chosen, reason = choose(ok, 0.005)
    assert chosen["model"] == "gltf_clearcoat"  # the rule alone: cheaper, within tolerance
    _layer_gains(ok)
    chosen, reason = _layer_no_worse_than_without(chosen, reason, ok, "log_rmse", _log_rule)
    assert chosen is ok[2], reason
    assert ("gltf_clearcoat passes the rule at log_rmse 0.009, above 0.0082 of "
            "generalized_schlick") in reason and reason.endswith("is chosen.")
    ok = rows(0.0082, 23.5)  # as close in log_rmse, but 1 dB worse to look at
    _layer_gains(ok)
    chosen, reason = _layer_no_worse_than_without(ok[1], "r", ok, "log_rmse", _log_rule)
    assert chosen is ok[2] and "renders 1.0 dB worse than generalized_schlick" in reason
    ok = rows(0.0081, 24.2)  # closer, and within 0.5 dB: the layer is taken
    _layer_gains(ok)
    assert _layer_no_worse_than_without(ok[1], "r", ok, "log_rmse", _log_rule) == (ok[1], "r")
    ok = rows(0.0081, float("nan"))  # a render not measured is no render 'inf dB worse'
    _layer_gains(ok)
    assert _layer_no_worse_than_without(ok[1], "r", ok, "log_rmse", _log_rule) == (ok[1], "r")


def test_a_budget_met_by_a_layered_candidate_is_not_overruled():
    """With a budget met, auto takes the cheapest candidate under it, layered or not: the
    guard's choice without a layer missed the budget (ggx at 0.0125 against 0.011), and
    was chosen while the reason said the budget was met."""
    from brdffit.selection import _layer_held_to_its_rule, choose

    rows = [{"model": m, "log_rmse": e, "psnr_db": db, "n_params": n, "verdict": "good",
             "radiance_verdict": "good"}
            for m, e, db, n in (("lambert", 0.05, 20.0, 4), ("gltf_pbr", 0.013, 30.6, 5),
                                ("gltf_clearcoat", 0.010, 29.0, 7), ("ggx", 0.0125, 31.0, 8))]
    chosen, reason = choose(rows, 0.005, 0.011)
    assert chosen["model"] == "gltf_clearcoat"
    assert _layer_held_to_its_rule(chosen, reason, rows, "log_rmse", 0.005, 0.011,
                                   True) == (chosen, reason)
    # no budget met: the tolerance rule decided, and the guard holds the layer to it
    chosen, reason = choose(rows, 0.005, 0.001)
    chosen, reason = _layer_held_to_its_rule(chosen, reason, rows, "log_rmse", 0.005,
                                             0.001, True)
    assert chosen["model"] == "gltf_pbr", reason
    assert "renders 1.6 dB worse than gltf_pbr, the choice among the candidates" in reason


def test_rechoose_replays_the_rule_and_its_guard_on_stored_rows():
    """``rechoose`` re-decides on ranking rows without refitting, as ``select`` decides:
    the tolerance rule (or the render rule) and the guard on a layered choice, on
    copies (the rows keep their statuses and ranks)."""
    from brdffit.selection import rechoose

    rows = [{"model": m, "log_rmse": e, "psnr_db": db, "views_psnr_db": db, "n_params": n,
             "verdict": "good", "radiance_verdict": "good", "status": "too far"}
            for m, e, db, n in (("gltf_pbr", 0.0104, 23.5, 5),
                                ("gltf_clearcoat", 0.0090, 24.4, 7),
                                ("generalized_schlick", 0.0082, 24.5, 11))]
    # the rule alone takes the cheaper coat; the guard, the closer fit without a layer
    assert rechoose(rows, "log", 0.005)["model"] == "generalized_schlick"
    assert rechoose(rows[:2], "log", 0.005)["model"] == "gltf_clearcoat"  # nothing to hold it to
    # the render rule takes the coat within its 0.5 dB; it renders no closer than the
    # choice without a layer, so that is chosen; more than 0.5 dB closer, the coat stays
    assert rechoose(rows, "render")["model"] == "generalized_schlick"
    rows[1]["views_psnr_db"] = 24.9  # closer, within the rule's 0.5 dB: alike
    assert rechoose(rows, "render")["model"] == "generalized_schlick"
    rows[1]["views_psnr_db"] = 25.1
    assert rechoose(rows, "render")["model"] == "gltf_clearcoat"
    assert [r["status"] for r in rows] == ["too far"] * 3 and "rank" not in rows[0]
    failed = [dict(rows[0], status="failed", log_rmse=None)]
    from brdffit.errors import FitInputError

    with pytest.raises(FitInputError, match="no fitted candidate"):
        rechoose(failed)
