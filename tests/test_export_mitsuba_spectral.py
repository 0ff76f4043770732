"""The Mitsuba export means the same in Mitsuba's spectral variants as in its RGB ones.

A sphere under the white directional light of ``validate.mitsuba_sphere`` renders to the
same mean colour in ``scalar_rgb`` (``load_dict(params)``) and ``scalar_spectral``
(``load_dict(params, spectral=True)``), each channel within 5%; what no spectra can
reproduce is refused, naming the variants. Small renders (64 px, 64 samples per pixel).
"""

from __future__ import annotations

import functools
import re

import numpy as np
import pytest

from brdffit.export import export, spectral_ior
from brdffit.export import mitsuba as mitsuba_export
from brdffit.export import validate as check
from brdffit.fitting import sphere as render
from brdffit.fitting.pipeline import fit
from data_synth import nbrdf
from tests.compiled_models import evaluate

pytestmark = pytest.mark.system

LIGHT = render.LIGHTS[0][1]
NO_DIFFUSE = {"kd": [0.0, 0.0, 0.0], "weight": 0.0}
CASES = {
    # eta > 1 with k = 0: an RGB srgb texture would clip it to 1 (no reflection at all)
    "eta 5, 10, 10": {"eta": [5.0, 10.0, 10.0], "k": [0.0, 0.0, 0.0], "alpha": 0.3,
                      **NO_DIFFUSE},
    "gold-like grey": {"eta": [0.2, 0.2, 0.2], "k": [3.9, 3.9, 3.9], "alpha": 0.3, **NO_DIFFUSE},
    "gold": {"eta": [0.143, 0.374, 1.442], "k": [3.983, 2.385, 1.603], "alpha": 0.2,
             **NO_DIFFUSE},
    "red diffuse": {"eta": [1.5, 1.5, 1.5], "k": [0.0, 0.0, 0.0], "alpha": 0.3,
                    "kd": [0.8, 0.1, 0.05], "weight": 1.0},
    # blue-metallic-paint's ggx export: a dark, saturated diffuse under a conductor,
    # which Mitsuba's own rgb upsampling rendered 8% too blue (kd as a fitted spectrum)
    "dark blue diffuse": {"eta": [3.75, 3.72, 10.0], "k": [0.95, 0.0, 4.7], "alpha": 0.26,
                          "kd": [0.0, 0.0, 0.00198], "weight": 0.807},
    # ... and its conductor fit: kd ~1e-8, 'black', which the rgb upsampling made 6% red
    "near-black diffuse": {"eta": [3.75, 3.72, 10.0], "k": [0.95, 0.0, 4.7], "alpha": 0.26,
                           "kd": [1.2e-8, 7.8e-9, 2e-11], "weight": 0.791},
}


def _mean_colour(material: dict, variant: str) -> np.ndarray:
    image = check.mitsuba_sphere(material, LIGHT, size=64, spp=64, variant=variant)
    return image.reshape(-1, 3).mean(axis=0)


def _agree(params: dict) -> None:
    rgb = _mean_colour(mitsuba_export.load_dict(params), "scalar_rgb")
    spectral = _mean_colour(mitsuba_export.load_dict(params, spectral=True), "scalar_spectral")
    np.testing.assert_allclose(spectral, rgb, rtol=0.05)


@functools.cache
def _real_params(material: str, model: str) -> dict:
    r = fit(nbrdf.make_table(material), model, samples=4096)
    return export(r, "mitsuba", target_model="rough_conductor").target_params  # eta, k


def test_the_light_is_white_in_both_variants():
    white = {"eta": [1.5] * 3, "k": [0.0] * 3, "alpha": 0.3, "kd": [1.0] * 3, "weight": 1.0}
    rgb = _mean_colour(mitsuba_export.load_dict(white), "scalar_rgb")
    spectral = _mean_colour(mitsuba_export.load_dict(white, spectral=True), "scalar_spectral")
    np.testing.assert_allclose(spectral, rgb, rtol=0.01)  # 0.4% measured (blue)


@pytest.mark.parametrize("case", list(CASES))
def test_spectral_sphere_has_the_rgb_colour(case):
    _agree(CASES[case])


@pytest.mark.parametrize("source", [("gold-metallic-paint", "rough_conductor"),
                                    ("red-plastic", "ggx")],  # the ggx fit is refitted
                         ids=["gold-metallic-paint", "red-plastic-ggx"])
def test_spectral_sphere_of_a_real_fit_has_the_rgb_colour(source):
    _agree(_real_params(*source))


def test_the_rgb_form_fails_in_a_spectral_variant():
    # why the spectral form exists: Mitsuba 3.6 clips an srgb eta to [0, 1] there
    params = CASES["eta 5, 10, 10"]
    rgb = _mean_colour(mitsuba_export.load_dict(params), "scalar_rgb")
    wrong = _mean_colour(mitsuba_export.load_dict(params), "scalar_spectral")
    assert rgb.min() > 0.05 and wrong.max() < 1e-3


def test_spectral_form_is_spectra_and_its_xml_loads():
    params = CASES["eta 5, 10, 10"]
    m = mitsuba_export.load_dict(params, spectral=True)
    eta = m["eta"]
    assert eta["type"] == "regular" and (eta["wavelength_min"], eta["wavelength_max"]) == (360, 830)
    assert len(eta["values"].split(",")) == spectral_ior.NODES.size
    grey = mitsuba_export.load_dict(CASES["gold-like grey"], spectral=True)
    assert (grey["eta"], grey["k"]) == (0.2, 3.9)  # equal channels: the numbers themselves
    mi = check.mitsuba("scalar_spectral")
    scene = mitsuba_export.scene_xml(m, "eta_5_10_10")
    assert '<spectrum name="eta" type="regular">' in scene
    body = scene.split("\n", 1)[1].rsplit("</scene>", 1)[0]
    bsdf = mi.load_string(re.sub(r' id="[^"]*"', ' version="3.0.0"', body, count=1))
    from_xml = _mean_colour(bsdf, "scalar_spectral")
    np.testing.assert_allclose(from_xml, _mean_colour(m, "scalar_spectral"), rtol=1e-6)


def test_the_form_is_picked_by_the_variant():
    params = CASES["gold"]
    assert mitsuba_export.load_dict_for_variant(params, "scalar_rgb") == \
        mitsuba_export.load_dict(params)
    assert mitsuba_export.load_dict_for_variant(params, "llvm_ad_spectral_polarized") == \
        mitsuba_export.load_dict(params, spectral=True)
    check.mitsuba("scalar_spectral")
    assert mitsuba_export.load_dict_for_variant(params)["eta"]["type"] == "regular"
    with pytest.raises(mitsuba_export.SpectralExportError, match="llvm_ad_mono"):
        mitsuba_export.load_dict_for_variant(params, "llvm_ad_mono")


def test_what_no_spectrum_reproduces_is_refused():
    # a saturated red mirror with no reflection at all in green and blue (eta = 1, k = 0):
    # no reflectance spectrum has that sRGB colour
    red = {"eta": [1.0, 1.0, 1.0], "k": [10.0, 0.0, 0.0], "alpha": 0.3, **NO_DIFFUSE}
    with pytest.raises(mitsuba_export.SpectralExportError, match="scalar_spectral"):
        mitsuba_export.load_dict(red, spectral=True)
    assert mitsuba_export.load_dict(red)["eta"]["type"] == "srgb"  # RGB variants: as ever


def test_rgb_variants_stay_exact_after_a_spectral_render():
    params = CASES["gold"]
    _mean_colour(mitsuba_export.load_dict(params, spectral=True), "scalar_spectral")
    rng = np.random.default_rng(0)
    v = rng.normal(size=(2, 500, 3))
    v[..., 2] = np.abs(v[..., 2]) + 1e-3
    v /= np.linalg.norm(v, axis=-1, keepdims=True)
    theirs = check.mitsuba_eval(mitsuba_export.load_dict(params), v[0], v[1])
    assert check.mitsuba().variant() in check.MITSUBA_VARIANTS  # back to an RGB variant
    from brdffit import models, runtime

    with runtime.float64():
        m = models.get("rough_conductor")
        ours = np.asarray(evaluate(m, m.check_params(params), v[0], v[1]))  # compiled
    big = ours > 1e-6 * ours.max()
    np.testing.assert_allclose(theirs[big], ours[big], rtol=1e-4)
