"""The standard_surface model against MaterialX's own shading of the standard_surface node
(and generalized_schlick against its generalized_schlick_bsdf over a diffuse).

Two checks:

- always: the JAX model against values MaterialX 1.39.5's generated GLSL computed
  (``brdffit.export.validate.materialx_eval`` on Mesa llvmpipe, float32, 2026-11-26),
  pinned below. The code path those values came from, in the generated pixel shader of
  ``NG_standard_surface_surfaceshader_100`` (``libraries/pbrlib/genglsl``):
  ``mx_roughness_anisotropy`` (alpha = roughness^2), ``mx_artistic_ior`` (the metal's n,
  k from base_color and specular_color), ``mx_conductor_bsdf`` and ``mx_dielectric_bsdf``
  (``mx_ggx_NDF``, ``mx_ggx_smith_G2``, ``mx_fresnel_conductor`` /
  ``mx_fresnel_dielectric`` at V.H, ``mx_ggx_energy_compensation`` with
  ``mx_ggx_dir_albedo_analytic``, the dielectric's throughput
  ``1 - dir_albedo * comp * weight``), ``mx_oren_nayar_diffuse_bsdf``
  (``mx_oren_nayar_diffuse``), ``mx_layer_bsdf`` (``top.response + base.response *
  top.throughput``), the metalness mix, and the light loop's ``intensity * response``
  divided by N.L (a BSDF's response is f_r cos_i);
- where the tool runs: the same generated GLSL evaluated now, on several parameter
  sets and a few hundred direction pairs each. Skipped only where moderngl is not
  installed or no OpenGL 4 context opens without a display (no libEGL or no Mesa
  driver); the skip says which.
"""

from __future__ import annotations

import functools

import numpy as np
import pytest

from brdffit import models
from brdffit.export import materialx
from brdffit.export import validate as check
from tests.compiled_models import evaluate

pytestmark = pytest.mark.unit


def _dir(theta, phi):
    t, p = np.radians(theta), np.radians(phi)
    return [np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)]


#: (theta, phi) in degrees of wi (the light) and wo (the view)
PAIRS = [((0, 0), (0, 0)), ((30, 0), (30, 180)), ((45, 0), (20, 90)), ((60, 30), (75, 200)),
         ((80, 0), (10, 180)), ((10, 0), (85, 0)), ((89, 0), (89, 180)), ((50, 0), (50, 0))]
WI = np.array([_dir(*a) for a, _ in PAIRS])
WO = np.array([_dir(*b) for _, b in PAIRS])

PLASTIC = {"base_color": [0.8, 0.35, 0.1], "metalness": 0.0,
           "specular_color": [1.0, 1.0, 1.0], "specular_roughness": 0.3, "specular_IOR": 1.5}
METAL = {"base_color": [0.9, 0.7, 0.3], "metalness": 1.0,
         "specular_color": [0.95, 0.9, 0.8], "specular_roughness": 0.25, "specular_IOR": 1.5}
BLEND = {"base_color": [0.2, 0.5, 0.9], "metalness": 0.4,
         "specular_color": [0.7, 0.8, 0.9], "specular_roughness": 0.08, "specular_IOR": 2.2}

#: MaterialX's generated GLSL's f_r (1/sr) at PAIRS, float32 (materialx_eval).
PINNED = [
    (PLASTIC, [[0.6369471, 0.4996969, 0.4234467], [0.7878236, 0.6502829, 0.5738714],
               [0.2454004, 0.1079626, 0.03160823], [0.3587721, 0.2445503, 0.1810936],
               [0.2456899, 0.1083866, 0.03210694], [0.1629878, 0.07182145, 0.02117349],
               [5893.242, 5893.163, 5893.118], [0.2428687, 0.1063554, 0.03051463]]),
    (METAL, [[18.30174, 14.24038, 6.107893], [24.4075, 18.97118, 8.242762],
             [0.01182334, 0.009194353, 0.003963867], [0.5546991, 0.4319413, 0.2681663],
             [0.01433896, 0.01112503, 0.005130233], [0.01050562, 0.008037951, 0.003461076],
             [17871.1, 18207.9, 18133.77], [0.001977069, 0.001533057, 0.0006530278]]),
    (BLEND, [[270.0903, 519.2682, 845.5161], [366.2459, 695.2339, 1130.897],
             [0.03281987, 0.08203792, 0.1476617], [0.02731708, 0.06634074, 0.118618],
             [0.03277935, 0.08192937, 0.1474637], [0.01221324, 0.03052166, 0.05493423],
             [4624474, 4966663, 5149590], [0.03265848, 0.08164435, 0.1469588]]),
]

#: standard_surface_coat: a coated plastic and a coated gold.
COATED_PLASTIC = {**PLASTIC, "specular_roughness": 0.5, "coat": 1.0, "coat_roughness": 0.1}
COATED_METAL = {**METAL, "specular_roughness": 0.4, "coat": 0.7, "coat_roughness": 0.3}
#: MaterialX's generated GLSL's f_r of the coated node at PAIRS (materialx_eval,
#: 2026-12-02).
PINNED_COAT = [
    (COATED_PLASTIC, [[32.11148, 31.97952, 31.90621], [44.35897, 44.22647, 44.15286],
                      [0.2404346, 0.1080967, 0.03457556], [0.4139793, 0.3187099, 0.2657824],
                      [0.2422692, 0.1102076, 0.03684005], [0.07931339, 0.03552323, 0.01119535],
                      [2104902.0, 2104902.0, 2104902.0], [0.2339757, 0.1030298, 0.03028208]]),
    (COATED_METAL, [[3.050928, 2.423681, 1.186995], [4.116818, 3.26226, 1.613347],
                    [0.06509187, 0.05047438, 0.02191953], [1.849045, 1.444663, 0.9218152],
                    [0.07636226, 0.05917744, 0.02761684], [0.0373096, 0.02855199, 0.01253302],
                    [4881.615, 4895.844, 4892.712], [0.01265703, 0.009747674, 0.004142258]]),
]

#: standard_surface_sheen: a velvet and a sharp blue sheen over a half-metal gold.
VELVET = {**PLASTIC, "base_color": [0.3, 0.05, 0.08], "specular_roughness": 0.8,
          "sheen": 1.0, "sheen_color": [0.9, 0.5, 0.6], "sheen_roughness": 0.3}
SHEENED_METAL = {**METAL, "metalness": 0.5, "specular_roughness": 0.4, "sheen": 0.6,
                 "sheen_color": [0.2, 0.5, 1.0], "sheen_roughness": 0.05}
PINNED_SHEEN = [
    (VELVET, [[0.09637864, 0.02274449, 0.03158059], [0.09592644, 0.02466386, 0.03321537],
              [0.1055279, 0.02777785, 0.03776873], [0.1460011, 0.1012897, 0.1067991],
              [0.1291132, 0.04256742, 0.05466298], [0.1012065, 0.04824189, 0.05832351],
              [16.29373, 16.28071, 16.28227], [0.1703772, 0.06622408, 0.08378405]]),
    (SHEENED_METAL, [[1.62572, 1.269124, 0.5651054], [2.140219, 1.665983, 0.7484756],
                     [0.1714852, 0.1334479, 0.05772329], [1.251102, 0.9867196, 0.6245339],
                     [0.1776463, 0.1382747, 0.06097762], [0.07065165, 0.05487635, 0.02428433],
                     [1050.882, 1034.755, 979.5934], [0.1404677, 0.1097112, 0.04816931]]),
]

#: Further parameter sets for the live comparison: grey, rough, high-index, bounds.
MORE = [
    {"base_color": [0.05, 0.05, 0.05], "metalness": 0.0,
     "specular_color": [1.0, 0.5, 0.2], "specular_roughness": 0.9, "specular_IOR": 1.2},
    {"base_color": [1.0, 1.0, 1.0], "metalness": 0.7,
     "specular_color": [0.2, 0.3, 1.0], "specular_roughness": 0.05, "specular_IOR": 3.0},
    {"base_color": [0.04, 0.03, 0.02], "metalness": 0.1,
     "specular_color": [0.3, 0.2, 0.1], "specular_roughness": 0.5, "specular_IOR": 18.0},
    {"base_color": [0.5, 0.5, 0.5], "metalness": 0.0,
     "specular_color": [0.9, 0.9, 0.9], "specular_roughness": 0.032, "specular_IOR": 50.0},
    {"base_color": [0.0, 0.3, 1.0], "metalness": 0.0,
     "specular_color": [0.0, 0.0, 0.0], "specular_roughness": 1.0, "specular_IOR": 1.0},
]


#: Coats for the live comparison: a faint broad one over a blend, a near-mirror one
#: (coat_roughness at its bound) over a rough dielectric, the roughest over a metal.
MORE_COAT = [
    {**BLEND, "specular_roughness": 0.6, "coat": 0.4, "coat_roughness": 0.05},
    {**MORE[0], "coat": 1.0, "coat_roughness": 0.0317},
    {**METAL, "coat": 0.5, "coat_roughness": 1.0},
]
#: Sheens for the live comparison: the sharpest (its albedo fit clamped at grazing
#: views) over a grey, the broadest over a blend.
MORE_SHEEN = [
    {**MORE[0], "sheen": 0.8, "sheen_color": [1.0, 1.0, 1.0], "sheen_roughness": 0.01},
    {**BLEND, "sheen": 0.4, "sheen_color": [0.3, 0.9, 0.1], "sheen_roughness": 1.0},
]

#: generalized_schlick (a generalized_schlick_bsdf layered over an oren_nayar_diffuse_bsdf):
#: a red lobe that turns blue-green away from normal incidence
TINTED = {"kd": [0.3, 0.15, 0.08], "color0": [0.6, 0.3, 0.2], "color90": [0.3, 0.6, 0.7],
          "exponent": 1.5, "alpha": 0.15}
#: MaterialX's generated GLSL's f_r at PAIRS (materialx_eval, 2026-12-06)
PINNED_TINTED = [
    (TINTED, [[2.207418, 1.097577, 0.7263001], [2.865485, 1.5249, 1.079151],
              [0.09976954, 0.05050576, 0.03008026], [1.033985, 0.9709621, 0.9459569],
              [0.1035817, 0.05719393, 0.03770402], [0.08620982, 0.04475976, 0.02716684],
              [421.3156, 824.8636, 962.4532], [0.06892242, 0.03439524, 0.01881844]]),
]
#: Its bounds for the live comparison: a near-mirror whose colour turns early, the
#: roughest with Schlick's curve and beyond, a black lobe, a white diffuse. (A channel
#: whose colour runs to 0 at grazing, color0 0.9 to color90 0 at exponent 0.2, is
#: 0.9 (1 - 0.9998) at 89.94 deg: the shader's float32 mix() loses 3e-4 of it there.)
MORE_TINTED = [
    {"kd": [0.0, 0.0, 0.0], "color0": [0.9, 0.1, 0.0], "color90": [0.2, 0.2, 1.0],
     "exponent": 0.2, "alpha": 0.002},
    {"kd": [1.0, 1.0, 1.0], "color0": [0.04, 0.04, 0.04], "color90": [1.0, 1.0, 1.0],
     "exponent": 20.0, "alpha": 1.0},
    {"kd": [0.5, 0.2, 0.9], "color0": [0.0, 0.0, 0.0], "color90": [0.0, 0.0, 0.0],
     "exponent": 5.0, "alpha": 0.3},
]


def _model(params, wi, wo):
    name = ("generalized_schlick" if "color90" in params
            else "standard_surface_coat" if "coat" in params
            else "standard_surface_sheen" if "sheen" in params else "standard_surface")
    m = models.get(name)
    return np.asarray(evaluate(m, m.check_params(params), wi, wo))  # compiled, not op by op


@pytest.mark.parametrize("params, pinned", PINNED + PINNED_COAT + PINNED_SHEEN + PINNED_TINTED,
                         ids=["plastic", "metal", "blend", "coated-plastic", "coated-metal",
                              "velvet", "sheened-metal", "tinted"])
def test_model_matches_materialx_glsl_values(params, pinned):
    # float32 shader values: agreement measured at 1.7e-6 relative at worst
    np.testing.assert_allclose(_model(params, WI, WO), pinned, rtol=1e-5)


@functools.cache
def _gl_missing() -> str | None:
    """Why MaterialX's GLSL cannot run here, or None."""
    try:
        import moderngl
    except ModuleNotFoundError:
        return "moderngl is not installed (pip install 'brdffit[export-check]')"
    try:
        moderngl.create_standalone_context(backend="egl", require=400).release()
    except Exception as exc:  # noqa: BLE001 - the driver's own words, in the skip
        return f"no headless OpenGL 4 context (EGL; Debian: libegl1 libgl1-mesa-dri): {exc}"
    return None


def _needs_gl():
    reason = _gl_missing()
    if reason:
        pytest.skip(reason)


def _random_pairs(n_light, n_view, seed):
    rng = np.random.default_rng(seed)

    def hemi(k):
        v = rng.normal(size=(k, 3))
        v[:, 2] = np.abs(v[:, 2])
        return v / np.linalg.norm(v, axis=1, keepdims=True)

    return np.repeat(hemi(n_light), n_view, 0), hemi(n_light * n_view)


@pytest.mark.parametrize("params", [PLASTIC, METAL, BLEND, *MORE, COATED_PLASTIC,
                                    COATED_METAL, *MORE_COAT, VELVET, SHEENED_METAL,
                                    *MORE_SHEEN, TINTED, *MORE_TINTED])
def test_model_matches_materialx_glsl_live(params):
    _needs_gl()
    wi, wo = _random_pairs(16, 20, seed=3)
    # and near grazing: cos 1e-3 and 0.02 for the light and the view
    edge = np.array([_dir(t, p) for t in (89.94, 88.9, 45.0) for p in (0.0, 120.0)])
    wi = np.vstack([wi, np.repeat(edge, len(edge), 0)])
    wo = np.vstack([wo, np.tile(edge[:, [0, 1, 2]] * [-1, -1, 1], (len(edge), 1))])
    # the directions as the shader receives them: rounding them to float32 moves a sharp
    # grazing peak (alpha 0.0064, 89.94 deg) by 4e-4 relative, on both sides alike
    wi, wo = (w.astype(np.float32).astype(np.float64) for w in (wi, wo))
    text = materialx.document(params, "check")  # the node, coated where params have a coat
    gl = check.materialx_eval(text, wi, wo)
    np.testing.assert_allclose(_model(params, wi, wo), gl, rtol=1e-4, atol=1e-9)


def test_pinned_values_are_what_materialx_computes_now():
    _needs_gl()
    for params, pinned in PINNED + PINNED_COAT + PINNED_SHEEN + PINNED_TINTED:
        text = materialx.document(params, "check")
        np.testing.assert_allclose(check.materialx_eval(text, WI, WO), pinned, rtol=1e-6)


@pytest.mark.parametrize("model, params", [
    ("standard_surface", PLASTIC),
    ("standard_surface_coat", COATED_PLASTIC),
    ("standard_surface_sheen", VELVET),
    ("generalized_schlick", TINTED),
    ("gltf_pbr", {"base_color": [0.8, 0.35, 0.1], "metallic": 0.4, "roughness": 0.45}),
    ("gltf_pbr_ior", {"base_color": [0.8, 0.35, 0.1], "metallic": 0.4, "roughness": 0.45,
                      "ior": 1.9}),
])
def test_documents_pass_materialx_validation(model, params):
    pytest.importorskip("MaterialX", reason="MaterialX is not installed (export-check extra)")
    text = materialx.document(params, "3 red/plastic", model)
    ok, message = check.materialx_validate(text)
    assert ok, message
    node = ("standard_surface" if model.startswith("standard_surface")
            else "generalized_schlick_bsdf" if model == "generalized_schlick" else "gltf_pbr")
    assert f"<{node} " in text
    assert materialx.document(params, "3 red/plastic") == text  # the model from the names


def test_the_export_writes_the_inputs_the_model_holds_fixed():
    from brdffit.models.standard_surface import FIXED_INPUTS
    from brdffit.models.standard_surface_coat import COAT_IOR

    assert materialx.STANDARD_SURFACE_FIXED == FIXED_INPUTS
    assert set(materialx.STANDARD_SURFACE_INPUTS) == {
        s.name for s in models.get("standard_surface").param_specs}
    assert materialx.COAT_FIXED == {"coat_IOR": COAT_IOR}
    for model, (layer, fixed) in materialx.LAYER_INPUTS.items():
        assert set(materialx.STANDARD_SURFACE_INPUTS) | set(layer) == {
            s.name for s in models.get(model).param_specs}
        assert not set(fixed) & set(layer)


def test_only_the_gltf_node_needs_the_shading_note():
    assert materialx.shading_notes("standard_surface") == []
    assert materialx.shading_notes("generalized_schlick") == []
    assert materialx.shading_notes("gltf_pbr") == [materialx.SHADING_NOTE]
    assert materialx.shading_notes("gltf_pbr_ior") == [materialx.SHADING_NOTE]


def test_document_refuses_other_models():
    with pytest.raises(ValueError, match="standard_surface"):
        materialx.document({"kd": [0.1] * 3}, "x", "ggx")
