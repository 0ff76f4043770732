"""glTF exports as Blender opens them: its own glTF importer (Debian's ``blender``
package, 3.4) and its Cycles render, through ``brdffit.export.validate.blender_import``.

Blender maps glTF to its Principled BSDF v1, whose diffuse is Burley's, without glTF's
(1 - F): brdffit's ``gltf_blender`` model. The render is compared pixel by pixel with
that model and with the spec's shading of the same preview scene, so the difference a
Blender user sees is measured, not assumed. CI installs Blender (.ci/run).
"""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest

from brdffit.export import export
from brdffit.export import validate as check
from brdffit.fitting.result import FitResult

pytestmark = pytest.mark.system

SIZE = 48
DIELECTRIC = {"base_color": [0.8, 0.2, 0.1], "metallic": 0.0, "roughness": 0.5}
METAL = {"base_color": [0.9, 0.7, 0.3], "metallic": 1.0, "roughness": 0.4}


@pytest.fixture(scope="module")
def blender() -> str:
    exe = shutil.which("blender")
    if exe is None:
        pytest.fail("Blender is not installed (Debian: apt-get install blender python3-numpy)")
    return exe


def _files(params, tmp_path, glb=False):
    fit = FitResult("gltf_pbr", params, {"log_rmse": 0.01}, True, "successful", 5, 0.1, {},
                    table="red.binary")
    e = export(fit, "gltf")
    (name, data), = e.file_bytes(glb=glb).items()
    path = tmp_path / name
    path.write_bytes(data)
    return e, path


@pytest.mark.parametrize("glb", [False, True])
def test_blenders_importer_puts_the_material_on_the_sphere(blender, tmp_path, glb):
    e, path = _files(DIELECTRIC, tmp_path, glb)
    got = check.blender_import(path, blender=blender)
    name = e.material["materials"][0]["name"]
    kinds = {o["type"] for o in got["objects"]}
    assert {"MESH", "CAMERA", "LIGHT"} <= kinds
    (mesh,) = [o for o in got["objects"] if o["type"] == "MESH"]
    assert mesh["materials"] == [name]
    inputs = got["materials"][name]["principled"]
    np.testing.assert_allclose(inputs["Base Color"][:3], DIELECTRIC["base_color"], rtol=1e-6)
    assert inputs["Metallic"] == DIELECTRIC["metallic"]
    assert inputs["Roughness"] == pytest.approx(DIELECTRIC["roughness"], rel=1e-6)


_RENDERS: dict = {}


def _cycles_over(model, params, tmp_path, blender):
    """Cycles' render of the file of ``params`` (rendered once per module) over
    ``model``'s shading of the same pixels, where the sphere is lit and seen."""
    key = json.dumps(params, sort_keys=True)
    if key not in _RENDERS:
        _, path = _files(params, tmp_path)
        _RENDERS[key] = check.blender_import(path, size=SIZE, samples=64,
                                             blender=blender)["image"]
    image = _RENDERS[key]
    shown = image[..., :3].reshape(-1, 3)
    wi, wo, hit, _ = check.gltf_preview_pairs(SIZE)
    inner = hit & (wi[:, 2] > 0.2) & (wo[:, 2] > 0.3)
    covered = image[..., 3].reshape(-1)[inner] > 0.99  # the sphere is where it should be
    assert np.mean(covered) > 0.98 and np.all(image[..., 3].reshape(-1)[~hit] < 0.5)
    return shown[inner] / check.preview_radiance(model, params, SIZE)[inner]


BLUE = {"base_color": [0.3, 0.5, 0.8], "metallic": 0.0, "roughness": 0.3}


def test_gltf_blender_is_what_cycles_renders_and_the_spec_is_not(blender, tmp_path):
    """brdffit's gltf_blender (Burley's diffuse, Principled v1's Fresnel) against Cycles,
    pixel by pixel: the median within 0.5% (measured: 0.05-0.09%), nine pixels in ten
    within 3% (64 samples per pixel of noise). The spec's shading of the same pixels: a
    metal is Cycles' to 1% (the scene, the light's strength and the lobe agree); a
    dielectric is 2-8% darker (measured 2026-11-28: 4.1..4.5% median), Burley's diffuse
    without glTF's (1 - F), as issue 42 measured on real materials (+1..+7% in Blender)."""
    for params in (METAL, DIELECTRIC, BLUE):
        ratio = _cycles_over("gltf_blender", params, tmp_path, blender)
        np.testing.assert_allclose(np.median(ratio, 0), 1.0, atol=0.005)
        assert np.percentile(np.abs(ratio.mean(1) - 1.0), 90) < 0.03
    metal = np.median(_cycles_over("gltf_pbr", METAL, tmp_path, blender), 0)
    np.testing.assert_allclose(metal, 1.0, atol=0.01)
    dielectric = np.median(_cycles_over("gltf_pbr", DIELECTRIC, tmp_path, blender), 0)
    assert np.all((dielectric > 1.02) & (dielectric < 1.08)), dielectric
