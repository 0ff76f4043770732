"""brdffit.export in process: exact copies of target-model fits, refits with their loss
reported for every other fit, a warning for every clamp, strict JSON, clear errors."""

from __future__ import annotations

import dataclasses
import json
import math
import re
import xml.etree.ElementTree as ET

import numpy as np
import pytest

from brdffit import models
from brdffit.errors import BrdffitError
from brdffit.export import SCHEMA, TARGETS, Export, ExportError, export, gltf
from brdffit.export.conversion import fit_as_table
from brdffit.fitting.problem import sphere_reference, table_error
from brdffit.fitting.result import FitResult

pytestmark = pytest.mark.unit

GLTF = {"base_color": [0.8, 0.35, 0.1], "metallic": 0.4, "roughness": 0.45}
CONDUCTOR = {"eta": [0.2, 0.9, 1.4], "k": [3.9, 2.4, 1.6], "alpha": 0.15,
             "kd": [0.3, 0.2, 0.1], "weight": 0.2}
GGX = {"kd": [0.2, 0.1, 0.05], "ks": [0.8, 0.7, 0.6], "alpha": 0.15, "f0": 0.6}


def result(model, params, **kw) -> FitResult:
    return FitResult(model, params, {"log_rmse": 0.02}, kw.pop("converged", True),
                     kw.pop("status", "successful"), 10, 0.1, {}, table="mats/gold.binary", **kw)


def test_gltf_fit_exports_exactly_to_gltf_and_materialx():
    r = result("gltf_pbr", GLTF)
    made = fit_as_table(r)  # the measured table: the fit's own BRDF, so it is met exactly
    g = export(r, "gltf", table=made)
    energy = {k: g.fidelity.pop(k) for k in ("albedo_max", "albedo_max_theta_deg")}
    to_table = g.fidelity.pop("log_rmse_to_table")
    colour = g.fidelity.pop("sphere_colour")
    psnr = g.fidelity.pop("render_psnr_db")
    viewers = g.fidelity.pop("viewers")
    assert viewers["spec"]["log_rmse_to_table"] == to_table
    assert viewers["spec"]["render_psnr_db"] == psnr
    assert g.fidelity == {"exact": True, "target_model": "gltf_pbr", "log_rmse_to_fit": 0.0,
                          "fit_log_rmse": 0.02, "renderer_model": "gltf_pbr",
                          "measured_on": "table"}
    # both spheres read the table's bins: the exact export is the table's colour
    assert to_table < 1e-6 and abs(colour["brightness_stops"]) < 1e-6
    assert abs(colour["displayed_brightness_stops"]) < 1e-6 and psnr > 60
    assert colour["colour_shift"] < 1e-3
    # metallic 0.4, as fitted: kept, and said (a measured material is a metal or not)
    assert 0 < max(energy["albedo_max"]) < 1
    assert [w for w in g.warnings if not w.startswith("class: 0.4 metal, as fitted")] == []
    (mat,) = g.material["materials"]
    assert g.material["asset"]["version"] == "2.0"
    assert mat["pbrMetallicRoughness"] == {"baseColorFactor": [0.8, 0.35, 0.1, 1.0],
                                           "metallicFactor": 0.4, "roughnessFactor": 0.45}
    assert json.loads(g.files["gold_gltf_pbr.gltf"]) == g.material

    x = export(r, "materialx", target_model="gltf_pbr")
    root = ET.fromstring(x.material)
    node = root.find("gltf_pbr")
    inputs = {i.get("name"): i.get("value") for i in node.findall("input")}
    assert inputs == {"base_color": "0.8, 0.35, 0.1", "metallic": "0.4", "roughness": "0.45"}
    assert root.find("surfacematerial/input").get("nodename") == node.get("name")
    # a look puts the material on whatever geometry a viewer loads
    assign = root.find("look/materialassign")
    assert assign.get("material") == root.find("surfacematerial").get("name")
    assert assign.get("geom") == "/*"
    # glTF's parameters, but MaterialX's own shading graph: not exact, and said
    assert not x.fidelity["exact"] and any("directional albedo" in w for w in x.warnings)


STANDARD = {"base_color": [0.8, 0.35, 0.1], "metalness": 0.2,
            "specular_color": [1.0, 0.9, 0.8], "specular_roughness": 0.45, "specular_IOR": 1.6}


def test_standard_surface_fit_exports_exactly_to_materialx():
    x = export(result("standard_surface", STANDARD), "materialx")
    assert x.fidelity["exact"] and x.fidelity["target_model"] == "standard_surface"
    assert x.fidelity["renderer_model"] == "standard_surface"
    assert not any("layers its specular" in w for w in x.warnings)  # MaterialX's own shading
    assert x.fidelity["log_rmse_to_fit"] == 0.0 and x.target_params == STANDARD
    root = ET.fromstring(x.material)
    node = root.find("standard_surface")
    inputs = {i.get("name"): i.get("value") for i in node.findall("input")}
    assert inputs == {"base": "1.0", "base_color": "0.8, 0.35, 0.1", "metalness": "0.2",
                      "specular": "1.0", "specular_color": "1.0, 0.9, 0.8",
                      "specular_roughness": "0.45", "specular_IOR": "1.6",
                      "diffuse_roughness": "0.0"}
    assert root.find("surfacematerial/input").get("nodename") == node.get("name")


def test_an_ior_fit_writes_khr_materials_ior():
    r = result("gltf_pbr_ior", {**GLTF, "ior": 1.9})
    g = export(r, "gltf")
    assert g.fidelity["exact"] and g.fidelity["target_model"] == "gltf_pbr_ior"
    assert g.material["extensionsUsed"] == ["KHR_lights_punctual", "KHR_materials_ior"]
    assert g.material["materials"][0]["extensions"] == {"KHR_materials_ior": {"ior": 1.9}}
    assert any("KHR_materials_ior" in w for w in g.warnings)  # viewers without it: 0.04
    x = ET.fromstring(export(r, "materialx", target_model="gltf_pbr_ior").material)
    assert x.find("gltf_pbr/input[@name='ior']").get("value") == "1.9"
    # a core fit's material uses no extension (the preview's light is one)
    core = export(result("gltf_pbr", GLTF), "gltf").material
    assert core["extensionsUsed"] == ["KHR_lights_punctual"]
    assert "extensions" not in core["materials"][0]


def test_the_gltf_file_is_a_scene_that_shows_the_material():
    """A viewer opens the file and sees the material: a sphere using it, a camera
    looking at it, a light from the sphere plots' key light; the material keeps its
    name. The .glb is the same document with its buffer in the binary chunk."""
    import base64
    import struct

    from brdffit.export import gltf

    doc = export(result("gltf_pbr", GLTF), "gltf").material
    (scene,) = doc["scenes"]
    nodes = [doc["nodes"][i] for i in scene["nodes"]]
    (mesh_node,) = [n for n in nodes if "mesh" in n]
    (primitive,) = doc["meshes"][mesh_node["mesh"]]["primitives"]
    assert doc["materials"][primitive["material"]]["name"] == "gold_gltf_pbr"
    positions = doc["accessors"][primitive["attributes"]["POSITION"]]
    assert positions["min"] == pytest.approx([-1, -1, -1], abs=1e-6)
    assert positions["max"] == pytest.approx([1, 1, 1], abs=1e-6)
    (camera_node,) = [n for n in nodes if "camera" in n]
    assert camera_node["translation"][2] > 1  # in front of the sphere, looking along -z
    (light_node,) = [n for n in nodes if "extensions" in n]
    light = doc["extensions"]["KHR_lights_punctual"]["lights"][
        light_node["extensions"]["KHR_lights_punctual"]["light"]]
    assert light["type"] == "directional" and light["intensity"] == pytest.approx(np.pi)
    x, y, z, w = light_node["rotation"]  # the light's -z turned to shine from upper left
    shine = -np.array([2 * (x * z + y * w), 2 * (y * z - x * w), 1 - 2 * (x * x + y * y)])
    assert shine == pytest.approx(-np.array(gltf.PREVIEW_LIGHT_FROM) / np.linalg.norm(
        gltf.PREVIEW_LIGHT_FROM), abs=1e-6)
    blob = base64.b64decode(doc["buffers"][0]["uri"].split(",", 1)[1])
    assert len(blob) == doc["buffers"][0]["byteLength"]

    glb = gltf.to_glb(doc)
    magic, version, length = struct.unpack_from("<4sII", glb)
    assert (magic, version, length) == (b"glTF", 2, len(glb))
    n_json, kind = struct.unpack_from("<I4s", glb, 12)
    head = json.loads(glb[20:20 + n_json])
    assert kind == b"JSON" and "uri" not in head["buffers"][0]
    assert head["materials"] == doc["materials"] and "uri" in doc["buffers"][0]  # unchanged
    n_bin, kind = struct.unpack_from("<I4s", glb, 20 + n_json)
    assert kind == b"BIN\0" and glb[28 + n_json:28 + n_json + len(blob)] == blob


@pytest.mark.slow
def test_conductor_fit_exports_exactly_to_mitsuba():
    r = result("rough_conductor", CONDUCTOR)
    e = export(r, "mitsuba", table=fit_as_table(r))
    from brdffit.export import mitsuba

    name = next(iter(e.files))[:-len(".xml")]  # NAME.xml, NAME_spectral.xml
    assert e.fidelity["exact"] and e.warnings == [mitsuba.VARIANTS_NOTE.replace("NAME", name)]
    m = e.material
    # both variant families' dictionaries are in the export (the JSON), each named
    assert e.variants["rgb"] == m and e.variants["spectral"]["type"] == "blendbsdf"
    assert "scalar_spectral" in e.variants["for"]["spectral"]
    assert e.variants["spectral"]["bsdf_0"]["eta"]["type"] == "regular"
    assert m["type"] == "blendbsdf" and m["weight"] == 0.2
    assert m["bsdf_0"] == {"type": "roughconductor", "distribution": "ggx", "alpha": 0.15,
                           "eta": {"type": "srgb", "color": [0.2, 0.9, 1.4], "unbounded": True},
                           "k": {"type": "srgb", "color": [3.9, 2.4, 1.6], "unbounded": True}}
    assert m["bsdf_1"] == {"type": "diffuse", "reflectance": {"type": "rgb",
                                                              "value": [0.3, 0.2, 0.1]}}
    # RGB variants read NAME.xml; spectral ones NAME_spectral.xml, eta and k as spectra
    assert set(e.files) == {"gold_rough_conductor.xml", "gold_rough_conductor_spectral.xml"}
    spectral = ET.fromstring(e.files["gold_rough_conductor_spectral.xml"])
    assert [x.get("name") for x in spectral.iter("spectrum")] == ["eta", "k", "reflectance"]
    # a colour no reflectance spectrum has: no spectral file, and a note that says why
    red = export(result("rough_conductor", {**CONDUCTOR, "eta": [1.0] * 3, "k": [10.0, 0.0, 0.0]}),
                 "mitsuba")
    assert list(red.files) == ["gold_rough_conductor.xml"] and red.variants["spectral"] is None
    assert any(w.startswith("spectral: ") and "scalar_spectral" in w for w in red.warnings)
    scene = ET.fromstring(e.files["gold_rough_conductor.xml"])
    bsdf = scene.find("bsdf")
    assert bsdf.get("id") == "gold_rough_conductor" and bsdf.get("type") == "blendbsdf"
    assert [b.get("type") for b in bsdf.findall("bsdf")] == ["roughconductor", "diffuse"]
    # a pure metal is the roughconductor alone
    pure = export(result("rough_conductor", {**CONDUCTOR, "weight": 0.0}), "mitsuba")
    assert pure.material["type"] == "roughconductor"


@pytest.mark.slow
def test_other_fits_are_refitted_and_their_loss_is_the_measured_one():
    r = result("ggx", GGX)
    e = export(r, "gltf")
    assert not e.fidelity["exact"] and e.fidelity["target_model"] == "gltf_pbr"
    loss = e.fidelity["log_rmse_to_fit"]
    assert 0 < loss < 0.05
    assert any(w.startswith("approximated: gltf_pbr") and f"{loss:.4g}" in w for w in e.warnings)
    # the reported loss is the target's parameters against the fitted BRDF, every bin
    measured = table_error(fit_as_table(r), "gltf_pbr", e.target_params)["log_rmse"]
    assert measured == pytest.approx(loss, rel=1e-9)
    # the same refit behind both glTF-model targets
    assert export(r, "materialx", target_model="gltf_pbr").target_params == e.target_params
    # MaterialX's default target is its standard_surface node, refitted the same way
    x = export(r, "materialx")
    assert not x.fidelity["exact"] and x.fidelity["target_model"] == "standard_surface"
    measured = table_error(fit_as_table(r), "standard_surface", x.target_params)["log_rmse"]
    # 5e-9 apart (measured): the reported figure is the refit's own, before its
    # parameters are written out as plain floats
    assert measured == pytest.approx(x.fidelity["log_rmse_to_fit"], rel=1e-6)
    assert "<standard_surface " in x.material


def test_every_clamp_is_a_warning():
    # a highlight brighter than any glTF base colour: base_color pinned at 1
    bright = result("ggx", {"kd": [0.9, 0.9, 0.9], "ks": [3.0, 3.0, 3.0], "alpha": 0.3,
                            "f0": 1.0})
    e = export(bright, "gltf")
    clamps = [w for w in e.warnings if w.startswith("clamp:")]
    pinned = [c for c, v in zip("RGB", e.target_params["base_color"], strict=True) if v >= 0.9999]
    (line,) = [w for w in clamps if w.startswith("clamp: base_color = ")]  # one per parameter
    assert pinned and all(f" {c} 1" in line for c in pinned) and "upper bound 1" in line
    assert "next: fit gltf_pbr to the table itself" in line
    # at the lower roughness bound
    sharp = export(result("gltf_pbr", {**GLTF, "roughness": float(np.sqrt(1e-3))}), "gltf")
    (line,) = [w for w in sharp.warnings if "roughness" in w and "lower bound" in w]
    # a fit of the target model itself is not told to fit that model again
    assert "next: nothing within gltf_pbr: this fit of it ended there" in line
    assert "to the table itself" not in line
    # principled's specular at 1 (F0 0.08) and its sharpest coat are its range, not a
    # weight: said (a refit of a gold coat ended there without a word)
    from brdffit.export.conversion import bound_warnings

    top = bound_warnings("principled_clearcoat", {
        "base_color": [0.9, 0.6, 0.2], "roughness": 0.3, "specular": 0.99999998, "sheen": 0.0,
        "sheen_tint": 0.0, "clearcoat": 1.0, "clearcoat_gloss": 0.99999999})
    assert [w.split(" =")[0] for w in top] == ["clamp: specular", "clamp: clearcoat_gloss"]


def test_an_index_of_one_is_a_matte_surface_not_a_clamp():
    """An index of 1 reflects nothing at the surface (F0 0, as a ggx f0 of 0): what a
    matte table asks for, not the renderer's range. A lambert fit's MaterialX refit ends
    there and was told it was clamped; a glTF ior of 1 likewise. A rough_plastic eta at
    its floor 1.001 is still said: 1 itself is outside its range."""
    from brdffit.export.conversion import bound_warnings

    matte = export(result("lambert", {"kd": [0.5, 0.35, 0.2]}), "materialx")
    assert matte.target_params["specular_IOR"] < 1.001
    assert not [w for w in matte.warnings if w.startswith("clamp:")], matte.warnings
    assert bound_warnings("gltf_pbr_ior", {**GLTF, "metallic": 0.0, "ior": 1.0}) == []
    assert [w.split(" is ")[0] for w in bound_warnings(
        "rough_plastic", {"kd": [0.5] * 3, "alpha": 0.1, "eta": 1.001, "ks": [0.5] * 3})] \
        == ["clamp: eta = 1.001"]


def test_a_material_that_reflects_more_than_it_receives_is_a_warning():
    # glTF's own formula: a white dielectric's albedo passes 1 towards grazing
    white = export(result("gltf_pbr", {"base_color": [1.0, 1.0, 1.0], "metallic": 0.0,
                                       "roughness": 0.5}), "gltf")
    assert max(white.fidelity["albedo_max"]) > 1.05
    assert white.fidelity["albedo_max_theta_deg"] >= 80
    assert any(w.startswith("energy: the gltf_pbr material reflects up to 1.1") for w in
               white.warnings)
    # the conductor conserves energy by construction, even at its brightest
    assert any("in R, G, B from" in w and "--physical" in w for w in white.warnings)
    bright = {"eta": [0.05] * 3, "k": [15.0] * 3, "alpha": 0.3, "kd": [1.0] * 3, "weight": 0.5}
    e = export(result("rough_conductor", bright), "mitsuba")
    assert max(e.fidelity["albedo_max"]) <= 1.0
    assert not any(w.startswith("energy") for w in e.warnings)


def test_an_unconverged_fit_says_so():
    e = export(result("gltf_pbr", GLTF, converged=False, status="nonlinear_max_steps_reached"),
               "gltf")
    assert any("did not converge" in w for w in e.warnings)


def test_export_json_is_strict_and_round_trips():
    e = export(result("rough_conductor", CONDUCTOR), "mitsuba")
    text = e.to_json()
    d = json.loads(text, parse_constant=lambda c: pytest.fail(f"non-strict JSON {c}"))
    assert d["schema"] == SCHEMA and Export.from_dict(d) == e
    with pytest.raises(ValueError, match="export schema"):
        Export.from_dict({**d, "schema": "brdffit.export/0"})


def test_bad_requests_are_clear_errors():
    with pytest.raises(ExportError, match="unknown export target 'blender'; choose one of "
                                          + ", ".join(TARGETS)):
        export(result("ggx", GGX), "blender")
    failed = FitResult("ggx", {}, {"log_rmse": float("nan")}, False, "nonfinite", 0, 0.0, {})
    with pytest.raises(ExportError, match="no parameters"):
        export(failed, "gltf")
    with pytest.raises(ValueError, match="roughness"):
        export(result("gltf_pbr", {**GLTF, "roughness": 3.0}), "gltf")
    # fits no table holds are said of the fit (they read as a corrupt or blank file)
    black = result("ggx", {**GGX, "kd": [0.0] * 3, "ks": [1e-30] * 3})
    with pytest.raises(ExportError, match="the ggx fit is black .*: nothing to export"):
        export(black, "gltf")
    glaring = result("ggx", {**GGX, "kd": [1e300] * 3})
    with pytest.raises(ExportError, match="the ggx fit reaches 3.18e\\+299 1/sr"):
        export(glaring, "mitsuba")


@pytest.mark.slow
def test_fidelity_to_the_measured_table_and_the_colour_a_sphere_shows():
    """A refit's error to the measured table is the exported material's own, under the
    renderer's semantics; a table not at hand is said, never guessed."""
    r = result("ggx", GGX)
    measured = fit_as_table(result("ggx", {**GGX, "ks": [0.9, 0.6, 0.6]}))  # a redder table
    e = export(r, "gltf", table=measured)
    expected = table_error(measured, "gltf_pbr", e.target_params)["log_rmse"]
    assert e.fidelity["log_rmse_to_table"] == pytest.approx(expected, rel=1e-9)
    colour = e.fidelity["sphere_colour"]
    # the export follows the fit, which is less red than the table: off in hue, and
    # in brightness (its green, which weighs most in luminance, is higher)
    assert colour["colour_shift"] > 1.0 and colour["brightness_stops"] > 0.01
    assert colour["estimate_error"]["colour_shift"] < 0.01
    # the figures of the fit's own quality block, from the same renders: an export of
    # a fit as it is (Mitsuba's ggx-like conductor is not; gltf's own model is) shows
    # what the fit's verdict judged
    own = result("gltf_pbr", GLTF)
    exact = export(own, "gltf", table=measured)
    psnr, look = sphere_reference(measured).psnr_and_colour(models.get("gltf_pbr"), GLTF)
    assert exact.fidelity["render_psnr_db"] == pytest.approx(psnr, rel=1e-9)
    assert exact.fidelity["sphere_colour"]["displayed_brightness_stops"] == pytest.approx(
        look["key"]["displayed_brightness_stops"], rel=1e-9)
    absent = export(r, "gltf")  # mats/gold.binary is not there
    assert absent.fidelity["log_rmse_to_table"] is None
    assert absent.fidelity["sphere_colour"] is None and absent.fidelity["render_psnr_db"] is None
    assert any(w.startswith("fidelity: log_rmse_to_table not measured") and "mats/gold.binary"
               in w for w in absent.warnings)


@pytest.mark.slow
def test_a_table_that_is_not_the_fits_own_is_said():
    """Measured against a table of another name than the fit's: a warning (a result
    keeps the table's name alone); the same name in another folder is the same table."""
    import dataclasses

    r = result("ggx", GGX)  # fitted on mats/gold.binary
    table = fit_as_table(r)
    other = export(r, "gltf", table=dataclasses.replace(table, source="elsewhere/silver.binary"))
    assert any("measured against elsewhere/silver.binary, but the fit was made on "
               "mats/gold.binary" in w for w in other.warnings), other.warnings
    moved = export(r, "gltf", table=dataclasses.replace(table, source="/data/gold.binary"))
    assert not any("the fit was made on" in w for w in moved.warnings), moved.warnings
    # another table judges the material, and does not make it: a metal fit judged against
    # a plastic's table had its class weighed on that table, and went out a dielectric
    from data_synth import make_table

    plastic = make_table("gltf_pbr", {"base_color": [0.5, 0.05, 0.02], "metallic": 0.0,
                                      "roughness": 0.3})[0]
    judged = export(r, "gltf", table=dataclasses.replace(plastic, source="other/red.binary"))
    assert judged.target_params == moved.target_params
    assert judged.fidelity["material_class"]["chosen"] == "metal mixture"
    assert "export: the material is made from the ggx fit, not from other/red.binary, which " \
           "only judges it" in judged.warnings
    assert judged.fidelity["log_rmse_to_table"] > 10 * moved.fidelity["log_rmse_to_table"]


def test_a_fits_own_table_file_changed_since_the_fit_is_said(tmp_path):
    """A result keeps its table's path alone: a file written over since (another
    material, or the same one rescaled) was measured against without a word."""
    from brdffit.io import merl
    from data_synth import make_table

    table, _ = make_table("ggx", GGX, noise=0.01, seed=3)
    path = tmp_path / "gold.binary"
    merl.write(path, table)
    own = dataclasses.replace(result("ggx", GGX), table=str(path),
                              error=table_error(merl.read(path), "ggx", GGX))
    assert not any("does not hold" in w for w in export(own, "gltf").warnings)
    merl.write(path, make_table("ggx", {**GGX, "ks": [0.3, 0.7, 0.9]})[0])
    changed = export(own, "gltf")
    assert any(w.startswith(f"fidelity: {path} does not hold the table that was fitted")
               for w in changed.warnings), changed.warnings
    assert changed.fidelity["log_rmse_to_table"] is not None  # measured, and said so


@pytest.mark.slow  # two exports, each a refit: ~5 s
def test_a_sample_lists_file_changed_since_the_fit_is_said(tmp_path):
    """A fit at a sample list's own directions is checked on the file's samples as
    they are now, by its log_rmse on every usable sample: another material written over
    the list was exported, refitted from it, without a word."""
    from brdffit.fitting.samples import sample_error
    from brdffit.io.readers import read_measured
    from brdffit.io.writers import write_csv
    from data_synth.sparse import sample_model

    path = tmp_path / "lab.csv"
    write_csv(sample_model("ggx", GGX, n=300, seed=4)[0], path)
    fitted = read_measured(path)
    own = dataclasses.replace(result("ggx", GGX), table=str(path),
                              input={"fitted_at": "samples"},
                              error=sample_error(fitted, "ggx", GGX))
    same = export(own, "gltf")
    assert not any("does not hold" in w for w in same.warnings)
    assert sorted(same.files) == ["lab_ggx.gltf"]  # not lab.csv_ggx.gltf
    write_csv(sample_model("ggx", {**GGX, "ks": [0.1, 0.1, 0.1], "alpha": 0.5}, n=300,
                           seed=4)[0], path)
    changed = export(own, "gltf")
    assert any(w.startswith(f"fidelity: {path} does not hold the samples that were fitted")
               for w in changed.warnings), changed.warnings


def test_a_fit_json_of_the_wrong_types_is_refused_by_its_key():
    """A result edited by hand or written by another tool: each key of the wrong JSON
    type is named (they failed deep in an export: "unhashable type: 'list'",
    "'NoneType' object has no attribute 'get'", ...); a metric that is null, as the
    schema allows, exports."""
    good = result("ggx", GGX, quality={"verdict": "poor", "reason": "r",
                                       "next": [{"try": "x", "why": "y"}]}).to_dict()
    for key, value, says in (
            ("model", ["ggx"], "'model' is a list, where a fit result has text"),
            ("error", None, "'error' is null, where a fit result has an object"),
            ("table", 5, "'table' is a whole number, where a fit result has text or null"),
            ("input", "x", "'input' is text, where a fit result has an object or null"),
            ("steps", True, "'steps' is true or false, where a fit result has a whole number"),
            ("error", {"log_rmse": "x"}, "error.log_rmse is text, where a fit result has a "
                                         "number or null"),
            ("quality", {"verdict": "poor", "next": ["x"]}, "quality.next is not a list of"),
            ("notes", [1], "notes is not a list of text")):
        with pytest.raises(ValueError, match=re.escape(says)):
            FitResult.from_dict({**good, key: value})
    with pytest.raises(BrdffitError, match="unknown result keys"):  # the shells' errors
        FitResult.from_dict({**good, "colour": 1})
    # strict JSON's null for a metric not measured reads back as the NaN the fit held
    unmeasured = FitResult.from_dict({**good, "error": {"log_rmse": None}})
    assert math.isnan(unmeasured.log_rmse) and not unmeasured.log_rmse < 1
    e = export(unmeasured, "mitsuba", target_model="principled")
    assert any("(the fit's own log_rmse to its table: not measured)" in w
               for w in e.warnings), e.warnings


def test_a_failed_fit_or_params_that_are_no_material_are_refused_naming_the_file(tmp_path):
    """A fit whose solve diverged (``result`` nonfinite) was exported with every fidelity
    figure under one warning; params out of range or missing were refused as
    "ggx: kd=[-1.0, 5.0, 1e+30] outside [0, inf]", naming neither the file nor the fit."""
    from brdffit import cli

    diverged = result("ggx", GGX, converged=False, status="nonfinite")
    with pytest.raises(ExportError, match=r"the ggx fit failed \(result nonfinite: its solve "
                                          r"diverged\): nothing to export"):
        export(diverged, "gltf")
    absurd = result("ggx", {**GGX, "kd": [-1.0, 5.0, 1e30]}, converged=False, status="stalled")
    with pytest.raises(ExportError, match=r"the ggx fit's parameters are not a ggx material "
                                          r"\(ggx: kd=.* outside"):
        export(absurd, "mitsuba")
    path = tmp_path / "diverged.json"
    path.write_text(json.dumps(diverged.to_dict()))
    assert cli.main(["export", str(path), "--to", "gltf"]) == 2
    stalled = result("ggx", GGX, converged=False, status="stalled")  # its last point: exported
    assert any("did not converge (stalled)" in w for w in export(stalled, "gltf").warnings)


def test_a_mitsuba_scene_file_names_any_material_in_well_formed_xml():
    """The material's id is an XML attribute: a table named R&D.csv wrote ``id="R&D..."``,
    a file no XML reader (Mitsuba's included) opens."""
    from brdffit.export import mitsuba

    text = mitsuba.scene_xml({"type": "diffuse"}, 'R&D "<lab>"_lambert')
    assert ET.fromstring(text).find("bsdf").get("id") == 'R&D "<lab>"_lambert'


@pytest.mark.slow
def test_an_export_of_a_fit_that_does_not_look_good_says_so():
    """An export cannot look better than the fit it carries: a poor or visible verdict
    is a warning, with the fit's first next step."""
    look = {"verdict": "poor", "reason": "sphere render 12.0 dB from the measurement",
            "next": [{"try": "--model ggx2", "why": "a second lobe", "gain_db": 2.0}]}
    r = result("ggx", GGX, quality=look)
    warned = [w for w in export(r, "gltf", table=fit_as_table(r)).warnings if "looks" in w]
    assert warned == ["the ggx fit looks poor beside its table: sphere render 12.0 dB from "
                      "the measurement; next: --model ggx2"]
    good = result("ggx", GGX, quality={**look, "verdict": "good", "next": []})
    assert not [w for w in export(good, "gltf", table=fit_as_table(r)).warnings if "looks" in w]


@pytest.mark.slow  # 9 s warm: make test runs it
def test_a_layered_gltf_file_is_judged_by_the_viewers_whose_shading_is_modelled():
    """The spec's definition takes in the extensions that define their BRDF: a
    KHR_materials_clearcoat, _iridescence or _ior file is its own model under "spec"
    (the export's own figures, exact); a KHR_materials_sheen file, whose BRDF the
    extension leaves to the viewer, has no spec model; three.js's are
    gltf_threejs_clearcoat, _iridescence and _sheen; and a viewer whose model lacks a
    layer is null, never another model's figures."""
    coated = {**GLTF, "clearcoat": 0.8, "clearcoat_roughness": 0.1}
    filmed = {**GLTF, "metallic": 1.0, "iridescence": 0.7, "iridescence_ior": 1.6,
              "iridescence_thickness": 400.0}
    sheened = {**GLTF, "sheen_color": [0.9, 0.5, 0.6], "sheen_roughness": 0.5}
    for model, params in (("gltf_clearcoat", coated), ("gltf_iridescence", filmed),
                          ("gltf_pbr_ior", {**GLTF, "ior": 1.6})):
        r = result(model, params)
        e = export(r, "gltf", table=fit_as_table(r))
        spec = e.fidelity["viewers"]["spec"]
        assert spec["model"] == model, e.fidelity["viewers"]
        assert spec["log_rmse_to_table"] == e.fidelity["log_rmse_to_table"] < 1e-6
        three = e.fidelity["viewers"]["threejs"]
        twin = {"gltf_clearcoat": "gltf_threejs_clearcoat",
                "gltf_iridescence": "gltf_threejs_iridescence"}.get(model)
        assert (three is None) == (twin is None), three  # ior: not modelled
        if twin is not None:
            assert three["model"] == twin
            # three.js's base and film are not the spec's: the figure is its own
            assert three["log_rmse_to_table"] > 1e-3
        # Blender shades its own coat; it ignores the film and the ior: the base's figure
        blender = e.fidelity["viewers"]["blender"]
        if model == "gltf_clearcoat":
            assert blender["model"] == "gltf_blender_clearcoat" and "ignores" not in blender
        else:
            assert blender["model"] == "gltf_blender"
            ignored = [k for k in params if k not in GLTF]
            assert blender["ignores"] == ignored
            assert blender["log_rmse_to_table"] == pytest.approx(table_error(
                fit_as_table(r), "gltf_blender",
                {k: v for k, v in params.items() if k not in ignored})["log_rmse"], rel=1e-12)
    r = result("gltf_sheen", sheened)
    measured = fit_as_table(r)
    sheen = export(r, "gltf", table=measured).fidelity
    viewers = sheen["viewers"]
    assert viewers["spec"] is None
    # the file carries the fit's own parameters, but no renderer's shading of it is
    # gltf_sheen: not exact (it was, with the headline figures no viewer shows)
    assert not sheen["exact"] and sheen["log_rmse_to_fit"] == 0.0
    assert all(e.fidelity["exact"] for e in (export(result("gltf_clearcoat", coated), "gltf"),))
    assert viewers["blender"]["model"] == "gltf_blender_sheen"
    assert viewers["threejs"]["model"] == "gltf_threejs_sheen"
    assert viewers["threejs"]["log_rmse_to_table"] == pytest.approx(
        table_error(measured, "gltf_threejs_sheen", sheened)["log_rmse"], rel=1e-12)
    # a velvet's base shaded as three.js does is not the spec's: the figure is its own
    assert viewers["threejs"]["log_rmse_to_table"] > 1e-3


@pytest.mark.slow  # the CLI's export with every viewer's refit: ~6 s
def test_the_cli_names_the_viewers_whose_shading_it_does_not_model(tmp_path, capsys):
    """A null viewer is said in the CLI's report, not left out (a silent line read as
    a good one)."""
    from brdffit import cli
    from brdffit.io import merl

    def exported(r) -> str:  # `brdffit export` of the fit against its own table: stderr
        fit_file = tmp_path / "fit.json"
        fit_file.write_text(json.dumps(r.to_dict()))
        merl.write(tmp_path / "t.binary", fit_as_table(r))
        assert cli.main(["export", str(fit_file), "--to", "gltf", "--measured",
                         str(tmp_path / "t.binary"), "--out", str(tmp_path)]) == 0
        return capsys.readouterr().err

    err = exported(result("gltf_sheen", {**GLTF, "sheen_color": [0.9, 0.5, 0.6],
                                         "sheen_roughness": 0.5}))
    assert "  in spec: not modelled" in err, err
    assert "  in threejs (gltf_threejs_sheen): log_rmse to the table " in err
    assert "  in blender (gltf_blender_sheen): log_rmse to the table " in err, err
    err = exported(result("gltf_clearcoat", {**GLTF, "clearcoat": 0.8,
                                             "clearcoat_roughness": 0.1}))
    assert "  in spec (gltf_clearcoat): log_rmse to the table " in err, err
    assert "  in threejs (gltf_threejs_clearcoat): log_rmse to the table " in err
    assert "  in blender (gltf_blender_clearcoat): log_rmse to the table " in err
    err = exported(result("gltf_pbr_ior", {**GLTF, "ior": 1.6}))  # three.js's physical one
    assert "  in threejs: not modelled" in err
    assert "(it ignores ior: shades the rest)" in err, err


def test_a_viewer_asked_of_a_target_without_viewers_is_refused_in_its_words():
    """A Mitsuba export asked for three.js's viewer was refused as "the glTF export is
    made for spec, threejs, blender; other targets have their renderer's own", which
    read as the glTF export refusing it: said of the export asked for."""
    r = result("gltf_pbr", GLTF)
    with pytest.raises(ExportError) as e:
        export(r, "mitsuba", viewer="threejs")
    assert str(e.value) == ("viewer 'threejs' is for the glTF export (spec, threejs, "
                            "blender); a Mitsuba export has its renderer's own shading")
    with pytest.raises(ExportError) as e:
        export(r, "gltf", viewer="unity")
    assert str(e.value) == "viewer 'unity': the glTF export's viewers are spec, threejs, blender"


@pytest.mark.slow
def test_a_gltf_export_reports_its_fidelity_in_each_viewer_and_fits_for_one():
    """fidelity.viewers: the file's factors under the spec's definition and under
    three.js's shading (gltf_threejs), each against the table; viewer="threejs" fits
    the factors for three.js on the measured table itself."""
    r = result("gltf_pbr", GLTF)
    measured = fit_as_table(result("ggx", {**GGX, "ks": [0.9, 0.6, 0.6]}))
    e = export(r, "gltf", table=measured)
    spec, three = e.fidelity["viewers"]["spec"], e.fidelity["viewers"]["threejs"]
    assert spec["model"] == "gltf_pbr" and three["model"] == "gltf_threejs"
    assert spec["log_rmse_to_table"] == e.fidelity["log_rmse_to_table"]
    assert three["log_rmse_to_table"] == pytest.approx(
        table_error(measured, "gltf_threejs", e.target_params)["log_rmse"], rel=1e-12)
    assert set(three["sphere_colour"]) == {"brightness_stops", "displayed_brightness_stops",
                                           "colour_shift", "displayed_colour_shift",
                                           "estimate_error"}
    assert three["render_psnr_db"] > 20
    for_three = export(r, "gltf", table=measured, viewer="threejs")
    assert for_three.fidelity["target_model"] == "gltf_threejs"
    assert not for_three.fidelity["exact"]
    assert any(w.startswith("refitted: gltf_threejs") for w in for_three.warnings)
    # three.js's model asked for by name is three.js's export (it was a conversion that
    # no viewer's refit made)
    by_name = export(r, "gltf", table=measured, target_model="gltf_threejs")
    assert by_name.target_params == for_three.target_params
    assert by_name.warnings == for_three.warnings
    # the refit is three.js's optimum: no worse there than the spec's file
    assert (for_three.fidelity["viewers"]["threejs"]["log_rmse_to_table"]
            <= three["log_rmse_to_table"] * 1.001)
    assert set(for_three.material["materials"][0]["pbrMetallicRoughness"]) == {
        "baseColorFactor", "metallicFactor", "roughnessFactor"}
    blender = e.fidelity["viewers"]["blender"]
    assert blender["model"] == "gltf_blender" and "ignores" not in blender
    assert blender["log_rmse_to_table"] == pytest.approx(
        table_error(measured, "gltf_blender", e.target_params)["log_rmse"], rel=1e-12)
    for_blender = export(r, "gltf", table=measured, viewer="blender")
    assert for_blender.fidelity["target_model"] == "gltf_blender"
    assert (for_blender.fidelity["viewers"]["blender"]["log_rmse_to_table"]
            <= blender["log_rmse_to_table"] * 1.001)
    ior = export(result("gltf_pbr_ior", {**GLTF, "ior": 1.6}), "gltf", table=measured)
    assert ior.fidelity["viewers"]["threejs"] is None  # three.js's model here has no ior
    # Blender's importer ignores KHR_materials_ior: it shades the factors at ior 1.5
    assert ior.fidelity["viewers"]["blender"]["ignores"] == ["ior"]
    assert ior.fidelity["viewers"]["blender"]["log_rmse_to_table"] == pytest.approx(
        table_error(measured, "gltf_blender", GLTF)["log_rmse"], rel=1e-12)
    with pytest.raises(ExportError, match="viewer 'threejs'"):
        export(r, "mitsuba", table=measured, viewer="threejs")
    with pytest.raises(ExportError, match="carries gltf_threejs"):
        export(r, "gltf", table=measured, viewer="threejs", target_model="gltf_pbr")


def test_a_refit_keeps_the_layers_the_fit_uses_where_a_model_layered_over_the_core_has_them():
    """The model a conversion refits: the core model, or the one layered over it that
    keeps most of the layers the fit uses (a weight above LAYER_IN_USE). Mitsuba's coat
    is a dielectric's, not layered over its rough_conductor: a coat is not carried
    there. A spec export never takes a viewer's twin."""
    from brdffit.export import _by_layers_kept

    coated = result("gltf_clearcoat", {**GLTF, "clearcoat": 0.8, "clearcoat_roughness": 0.1})
    bare = result("gltf_clearcoat", {**GLTF, "clearcoat": 1e-9, "clearcoat_roughness": 0.1})
    principled = {"base_color": [0.5, 0.2, 0.1], "roughness": 0.45, "specular": 0.5,
                  "sheen_tint": 0.5}
    first = {name: _by_layers_kept(TARGETS[name].target_models, coated)[0]
             for name in ("gltf", "materialx", "mitsuba")}
    assert first == {"gltf": "gltf_clearcoat", "materialx": "standard_surface_coat",
                     "mitsuba": "rough_conductor"}
    assert _by_layers_kept(TARGETS["materialx"].target_models, bare)[0] == "standard_surface"
    for sheen, want in ((0.0, "gltf_pbr"), (0.6, "gltf_sheen")):
        r = result("principled", {**principled, "sheen": sheen})
        assert _by_layers_kept(TARGETS["gltf"].target_models, r)[0] == want
    assert _by_layers_kept(gltf.VIEWER_MODELS["threejs"], coated)[0] == "gltf_threejs_clearcoat"
    assert _by_layers_kept(gltf.VIEWER_MODELS["blender"], coated)[0] == "gltf_blender_clearcoat"
    assert _by_layers_kept(TARGETS["gltf"].target_models, result("ggx", GGX))[0] == "gltf_pbr"


@pytest.mark.slow
def test_a_layered_fit_exported_for_a_viewer_keeps_the_layers_that_viewer_shades():
    """viewer="threejs" refits a coat fit as three.js's coat (gltf_threejs_clearcoat),
    the file keeping KHR_materials_clearcoat, and no worse in three.js than the spec's
    file; viewer="blender" as Blender's coat. Blender reads no film: a film fit for it
    is its core material, and the warning says that the film was lost."""
    coated = {**GLTF, "clearcoat": 0.8, "clearcoat_roughness": 0.1}
    r = result("gltf_clearcoat", coated)
    measured = fit_as_table(r)
    spec_file = export(r, "gltf", table=measured)
    for_three = export(r, "gltf", table=measured, viewer="threejs")
    assert for_three.fidelity["target_model"] == "gltf_threejs_clearcoat"
    assert gltf.CLEARCOAT_EXTENSION in for_three.material["extensionsUsed"]
    three = for_three.fidelity["viewers"]["threejs"]
    assert three["model"] == "gltf_threejs_clearcoat"
    assert (three["log_rmse_to_table"]
            <= spec_file.fidelity["viewers"]["threejs"]["log_rmse_to_table"] * 1.001)
    assert not any(w.startswith("layer:") for w in for_three.warnings)
    for_blender = export(r, "gltf", table=measured, viewer="blender")
    assert for_blender.fidelity["target_model"] == "gltf_blender_clearcoat"
    assert gltf.CLEARCOAT_EXTENSION in for_blender.material["extensionsUsed"]
    assert (for_blender.fidelity["viewers"]["blender"]["log_rmse_to_table"]
            <= spec_file.fidelity["viewers"]["blender"]["log_rmse_to_table"] * 1.001)
    filmed = result("gltf_iridescence", {**GLTF, "iridescence": 0.7, "iridescence_ior": 1.6,
                                         "iridescence_thickness": 400.0})
    for_blender = export(filmed, "gltf", table=fit_as_table(filmed), viewer="blender")
    assert for_blender.fidelity["target_model"] == "gltf_blender"
    assert gltf.IRIDESCENCE_EXTENSION not in for_blender.material.get("extensionsUsed", [])
    assert any(w.startswith("layer: the iridescence of the gltf_iridescence fit")
               for w in for_blender.warnings), for_blender.warnings


def test_a_glTF_refit_that_comes_out_a_metal_mixture_is_weighed_against_a_dielectric():
    """A plastic refitted as '95% metal' is exported as a dielectric where one does as
    well or the table has a diffuse body (no metal has one), the mixture's error
    beside it; a metal stays a metal, the dielectric's error said."""
    from brdffit.export.conversion import Conversion, dielectric_or_mixture

    fit = result("ggx", GGX)
    plastic = fit_as_table(result("gltf_pbr", {"base_color": [0.6, 0.3, 0.2], "metallic": 0.0,
                                               "roughness": 0.5}))
    mixture = Conversion("gltf_pbr", {"base_color": [0.6, 0.3, 0.2], "metallic": 0.9,
                                      "roughness": 0.5}, False, 0.01)
    conv, report = dielectric_or_mixture(fit, mixture, plastic)
    assert report["chosen"] == "dielectric" and conv.params["metallic"] == 0.0
    assert report["dielectric_log_rmse"] < 1e-4 < report["mixture_log_rmse"]
    assert any(w.startswith("class: exported as a dielectric") for w in conv.warnings)
    gold = {"base_color": [0.95, 0.7, 0.3], "metallic": 1.0, "roughness": 0.3}
    metal = fit_as_table(result("gltf_pbr", gold))
    kept, report = dielectric_or_mixture(fit, Conversion("gltf_pbr", {**gold, "metallic": 0.97},
                                                         False, 0.01), metal)
    assert report["chosen"] == "metal mixture" and kept.params["metallic"] == 0.97
    assert report["diffuse_body"] < 0.1 < report["dielectric_log_rmse"] / report[
        "mixture_log_rmse"]
    assert any(w.startswith("class: kept the metal mixture") for w in kept.warnings)
    exact = Conversion("gltf_pbr", gold, True, 0.0)  # a gltf_pbr fit is copied as it is
    assert dielectric_or_mixture(fit, exact, metal) == (exact, None)


@pytest.mark.parametrize("mixture_model, mixture, dielectric, is_dielectric", [
    ("rough_conductor", {"eta": [0.2, 0.4, 1.4], "k": [3.9, 2.4, 1.6], "alpha": 0.25,
                         "kd": [0.3, 0.3, 0.3], "weight": 0.1},
     "rough_plastic", lambda p: "k" not in p),
    ("standard_surface", {"base_color": [0.95, 0.75, 0.3], "metalness": 0.9,
                          "specular_color": [1.0, 1.0, 1.0], "specular_roughness": 0.4,
                          "specular_IOR": 1.5},
     "standard_surface", lambda p: p["metalness"] == 0.0),
])
@pytest.mark.slow
def test_mitsuba_and_materialx_weigh_a_metal_mixture_too(mixture_model, mixture, dielectric,
                                                         is_dielectric):
    """Mitsuba's conductor blend against its roughplastic, MaterialX's metalness against
    metalness 0: a plastic's table goes out a dielectric, a metal's stays a metal."""
    from brdffit.export.conversion import Conversion, dielectric_or_mixture

    fit = result("ggx", GGX)
    plastic = fit_as_table(result("rough_plastic", {"kd": [0.6, 0.3, 0.2], "alpha": 0.3,
                                                    "eta": 1.5, "ks": [1.0] * 3}))
    conv, report = dielectric_or_mixture(fit, Conversion(mixture_model, mixture, False, 0.01),
                                         plastic)
    assert report["chosen"] == "dielectric" and report["dielectric_model"] == dielectric
    assert conv.target_model == dielectric and is_dielectric(conv.params)
    metal = fit_as_table(result(mixture_model, mixture))
    kept, report = dielectric_or_mixture(fit, Conversion(mixture_model, mixture, False, 0.01),
                                         metal)
    assert report["chosen"] == "metal mixture", report
    assert kept.target_model == mixture_model and not is_dielectric(kept.params)


def test_a_lambert_fit_goes_to_mitsuba_as_its_diffuse_plugin_exactly():
    """Mitsuba's ``diffuse`` is kd/pi: a lambert fit is copied to it, not refitted as a
    conductor blend (Mitsuba's own evaluation of it: tests/test_export_tools.py)."""
    e = export(result("lambert", {"kd": [0.5, 0.35, 0.2]}), "mitsuba")
    assert e.fidelity["exact"] and e.fidelity["target_model"] == "lambert"
    assert e.material == {"type": "diffuse",
                          "reflectance": {"type": "rgb", "value": [0.5, 0.35, 0.2]}}
    assert '<bsdf type="diffuse" id=' in next(iter(e.files.values()))
    assert e.variants["spectral"]["type"] == "diffuse"
    assert not [w for w in e.warnings if w.startswith(("approximated:", "clamp:", "class:"))]


@pytest.mark.slow  # a refit of Mitsuba's conductor blend, and its class weighed (~8 s)
def test_a_lambert_fit_brighter_than_one_goes_to_mitsuba_within_its_range():
    """kd [1.22, 1.18, 1.15] was copied to Mitsuba's diffuse, which refused to load the
    file ("Invalid RGB reflectance value ... must be in the range [0, 1]"), exit 0 and
    no word: it is refitted within Mitsuba's range, said, and the clamp named; asked
    for lambert by name, it is refused."""
    from brdffit.export import ExportError

    bright = result("lambert", {"kd": [1.22, 1.18, 1.15]})
    e = export(bright, "mitsuba")
    assert e.fidelity["target_model"] == "rough_conductor" and not e.fidelity["exact"]
    assert e.fidelity["log_rmse_to_fit"] > 0.01
    assert any(w.startswith("range: kd [1.22, 1.18, 1.15] is above 1, which Mitsuba's "
                            "diffuse reflectance cannot hold") for w in e.warnings), e.warnings
    assert any(w.startswith("clamp: kd = R 1") for w in e.warnings), e.warnings
    assert max(e.material["bsdf_1"]["reflectance"]["value"]) <= 1.0
    with pytest.raises(ExportError, match="Mitsuba cannot load it"):
        export(bright, "mitsuba", target_model="lambert")


def test_names_a_renderer_refuses_are_made_its_own():
    """A table named "_lab" gave Mitsuba files that did not load ("leading underscores
    are reserved"), one named "金 red plastic" MaterialX documents that validate()
    refused ("Invalid element name"): both were written without a word."""
    import re

    from brdffit.export import materialx, mitsuba

    xml = mitsuba.scene_xml({"type": "diffuse", "reflectance": {"type": "rgb",
                                                                "value": [0.5] * 3}}, "_lab")
    assert 'id="lab"' in xml
    e = export(result("standard_surface", STANDARD), "materialx", name="金 red plastïc")
    text = next(v for v in e.files.values() if isinstance(v, str))
    names = re.findall(r'<\w+ name="([^"]+)"', text)
    assert names and all(n.isascii() for n in names), names
    assert any("red_plastic" in n for n in names), names
    assert materialx is not None


def test_a_diffuse_fit_goes_to_mitsuba_with_a_black_conductor_and_no_class_weighing():
    """A pure diffuse fit's refit to Mitsuba's conductor blend has a conductor that
    reflects nothing (eta ~1, k ~0, alpha wherever): no metal to weigh against a
    dielectric (that refit cost ~5 s and 'kept the metal mixture'), no clamp on the
    parameters that shape nothing, and the blend is the fit to 1e-6. (An Oren-Nayar of
    no roughness is Lambert's; a lambert fit itself is copied to ``diffuse``.)"""
    from brdffit.export import mitsuba
    from brdffit.export.conversion import CLASS_ALTERNATIVES

    e = export(result("oren_nayar", {"kd": [0.5, 0.35, 0.2], "sigma": 0.0}), "mitsuba")
    assert e.fidelity["target_model"] == "rough_conductor"
    assert e.fidelity["log_rmse_to_fit"] < 1e-6
    assert "material_class" not in e.fidelity
    assert not [w for w in e.warnings if w.startswith(("clamp:", "class:"))], e.warnings
    assert any("conductor reflects nothing" in w for w in e.warnings), e.warnings
    assert mitsuba.VARIANTS_NOTE.replace("NAME", next(iter(e.files))[:-4]) in e.warnings
    # a conductor that reflects is a metal, however little of the blend it is
    fraction = CLASS_ALTERNATIVES["rough_conductor"].metal_fraction
    assert fraction({**CONDUCTOR, "weight": 0.9}) == pytest.approx(0.1)
    assert fraction({**CONDUCTOR, "eta": [1.0] * 3, "k": [0.0] * 3, "weight": 0.2}) == 0.0


def test_a_sample_lists_export_is_measured_on_the_bins_its_samples_fall_in(tmp_path):
    """A fit of samples is measured at the samples, its export on the MERL bins they
    fall in: the fidelity says so (an exact export read "0.009137 (the fit's 0.01898)",
    as if it were twice better than its own fit)."""
    from brdffit import fit
    from brdffit.io.readers import read_measured
    from data_synth.__main__ import main as synth

    path = tmp_path / "lab.csv"
    assert synth(["samples", str(path), "--layout", "uniform", "-n", "400"]) == 0
    r = fit(read_measured(path), "gltf_pbr")
    out = export(r, "gltf")
    assert out.fidelity["exact"] and out.fidelity["measured_on"] == "binned samples"


def test_an_exact_copy_of_a_half_metal_says_so():
    """A fabric's gltf_sheen fit at metallic 0.44 went to glTF without a word: kept (the
    fit is the user's choice of class), and said; a metal or a dielectric is not."""
    sheen = {"base_color": [0.6, 0.2, 0.3], "metallic": 0.44, "roughness": 0.6,
             "sheen_color": [0.3, 0.1, 0.1], "sheen_roughness": 0.5}
    said = [w for w in export(result("gltf_sheen", sheen), "gltf").warnings
            if w.startswith("class: 0.44 metal, as fitted")]
    assert len(said) == 1 and "gltf_pbr_dielectric" in said[0]
    for metallic in (0.0, 1.0):
        plain = export(result("gltf_sheen", {**sheen, "metallic": metallic}), "gltf")
        assert not any(w.startswith("class:") for w in plain.warnings), plain.warnings
    # refits that are not weighed against a dielectric say it too: a layered fit to
    # MaterialX's sheen, a viewer's, one asked for (metallic 0.28-0.51 went unsaid)
    for target, kw in (("materialx", {}), ("gltf", {"viewer": "threejs"}),
                       ("gltf", {"target_model": "gltf_pbr"})):
        made = export(result("gltf_sheen", sheen), target, **kw)
        fraction = next(float(np.mean(made.target_params[k])) for k in
                        ("metallic", "metalness") if k in made.target_params)
        said = [w for w in made.warnings if w.startswith("class:")]
        assert 0.05 < fraction < 0.95, (target, kw, fraction)  # the refits stay half-metal
        assert len(said) == 1 and "refit came out (not weighed" in said[0], made.warnings
        assert "brdffit fit TABLE --model " in said[0]


def test_a_layers_tint_or_roughness_at_its_upper_bound_is_a_clamp_unless_the_layer_is_nil():
    """A sheen's or a coat's roughness, a specular colour, at the top of the renderer's
    range: the fit wanted more (red-plastic's sheen left glTF at sheenRoughnessFactor
    0.99999975, unsaid). A weight of 1 is a material, not a clamp; and a layer of no
    weight shapes nothing, so its parameters at a bound are no clamp either (a lambert
    fit's MaterialX refit: specular_IOR 1, specular_color 1)."""
    from brdffit.export.conversion import bound_warnings

    def clamped(model, params):
        return [w.split(" = ")[0] for w in bound_warnings(model, params)]

    sheen = {**GLTF, "sheen_color": [0.3, 0.2, 0.1], "sheen_roughness": 0.99999975}
    assert clamped("gltf_sheen", sheen) == ["clamp: sheen_roughness"]
    assert clamped("gltf_sheen", {**sheen, "sheen_color": [0.0] * 3}) == []
    coat = {"base_color": [0.5] * 3, "metalness": 0.0, "specular_color": [1.0, 0.7, 0.2],
            "specular_roughness": 0.3, "specular_IOR": 1.5, "coat": 1.0,
            "coat_roughness": 0.99999962}
    assert clamped("standard_surface_coat", coat) == ["clamp: specular_color",
                                                      "clamp: coat_roughness"]
    assert clamped("standard_surface_coat", {**coat, "coat": 0.0, "specular_IOR": 1.0}) == []


def test_a_refit_keeps_the_fits_loss_and_a_file_rendering_below_its_fit_is_said(monkeypatch):
    """A render-loss fit converted to another renderer's model is refitted under the
    render loss (under the log loss nickel's rough_conductor left glTF 17 dB below the
    fit's picture); and where a file's sphere renders over 3 dB below the fit's own, a
    warning says so."""
    from brdffit.export import _renders_below_the_fit
    from brdffit.export.conversion import convert
    from brdffit.fitting import pipeline

    asked = {}
    real = pipeline.fit

    def fit(table, model, **kw):
        asked.update(kw)
        return real(table, model, **{**kw, "loss": "log"})  # the point is what was asked

    monkeypatch.setattr(pipeline, "fit", fit)
    conv = convert(result("ggx", {"kd": [0.1] * 3, "ks": [0.5] * 3, "alpha": 0.2, "f0": 0.9},
                          loss="render"), ("gltf_pbr",))
    assert asked["loss"] == "render"
    assert "fit at every bin above the horizon with the render loss;" in conv.warnings[0]
    fitted = result("ggx", {}, quality={"render_psnr_db": 31.8})
    (said,) = _renders_below_the_fit(fitted, {"render_psnr_db": 14.1})
    assert said.startswith("fidelity: the file's sphere renders 14.1 dB from the table, "
                           "17.7 dB below the ggx fit's own 31.8 dB")
    assert _renders_below_the_fit(fitted, {"render_psnr_db": 29.0}) == []
    assert _renders_below_the_fit(result("ggx", {}), {"render_psnr_db": 14.1}) == []


def test_the_cli_finds_a_fits_table_beside_its_json(tmp_path, monkeypatch):
    """A fit's JSON names its table as typed where it was fitted; exported from another
    directory, the table was not found, and the material was made without it (a car
    paint left MaterialX as 88% metal there and as a dielectric beside its table)."""
    from brdffit.cli.export import _table_beside

    (tmp_path / "fits").mkdir()
    (tmp_path / "fits" / "gold.binary").write_bytes(b"")
    (tmp_path / "elsewhere").mkdir()
    monkeypatch.chdir(tmp_path / "elsewhere")
    fitted = dataclasses.replace(result("ggx", {}), table="gold.binary")
    found = _table_beside(fitted, str(tmp_path / "fits" / "gold.json"))
    assert found.table == str(tmp_path / "fits" / "gold.binary")
    # here, absolute, read from stdin, or beside neither: as it was
    (tmp_path / "elsewhere" / "gold.binary").write_bytes(b"")
    assert _table_beside(fitted, str(tmp_path / "fits" / "gold.json")) is fitted
    assert _table_beside(fitted, "-") is fitted
    gone = dataclasses.replace(fitted, table="missing.binary")
    assert _table_beside(gone, str(tmp_path / "fits" / "gold.json")) is gone


def test_exports_for_a_viewer_or_as_another_model_have_names_of_their_own():
    """One fit exported for the spec and for three.js, or as two of Mitsuba's models,
    into one folder: the second overwrote the first (both gold_gltf_pbr.gltf)."""
    from brdffit.export import _material_name

    r = result("gltf_pbr", GLTF)
    assert _material_name(r) == "gold_gltf_pbr"
    assert _material_name(r, "threejs") == "gold_gltf_pbr_threejs"
    assert _material_name(r, "spec", "principled_clearcoat") == \
        "gold_gltf_pbr_as_principled_clearcoat"
    assert _material_name(r, "spec", "gltf_pbr") == "gold_gltf_pbr"  # its own model
    made = fit_as_table(r)
    spec, threejs = (export(r, "gltf", table=made, viewer=v) for v in ("spec", "threejs"))
    assert list(spec.files) == ["gold_gltf_pbr.gltf"]
    assert list(threejs.files) == ["gold_gltf_pbr_threejs.gltf"]
