"""Checks of an export with the renderers' own tools: Mitsuba 3, MaterialX, the Khronos
glTF validator. Needs the ``export-check`` extra (and Node.js for glTF); fitting and
exporting never do.

- :func:`mitsuba_eval` evaluates an exported Mitsuba material with Mitsuba itself
  (``BSDF.eval`` returns f_r cos_o; divided here, so it compares with a model's f_r);
- :func:`mitsuba_log_rmse` is the fidelity *measured in Mitsuba*: the loss of
  ``brdffit.fitting.loss`` between Mitsuba's values of the export and the fitted
  BRDF, on every bin above the horizon (the bins the export's reported
  ``log_rmse_to_fit`` is computed on);
- :func:`mitsuba_sphere` renders the unit sphere of ``brdffit.fitting.sphere`` (orthographic
  camera along -z, a directional light of irradiance pi) with Mitsuba's path tracer;
- :func:`materialx_validate`, :func:`gltf_validate`: the tools' own document checks.
"""

from __future__ import annotations

import importlib
import json
import shutil
import subprocess

import numpy as np

from brdffit.errors import BrdffitError
from brdffit.extras import MissingExtraError
from brdffit.io.grid import bin_grid

#: Vectorised (needs the LLVM library at run time) first; scalar_rgb needs nothing.
MITSUBA_VARIANTS = ("llvm_ad_rgb", "scalar_rgb")


def _import(module: str, who: str):
    try:
        return importlib.import_module(module)
    except ModuleNotFoundError:
        raise MissingExtraError(who, "export-check", (module,)) from None


def mitsuba(variant: str | None = None):
    """The ``mitsuba`` module with a variant set: ``variant`` (e.g. ``"scalar_spectral"``),
    or by default an RGB one (the first of MITSUBA_VARIANTS that runs here)."""
    mi = _import("mitsuba", "brdffit.export.validate.mitsuba")

    if variant is not None:
        if variant not in mi.variants():
            raise RuntimeError(f"Mitsuba variant {variant!r} is not built here; "
                               f"these are: {', '.join(mi.variants())}")
        if mi.variant() != variant:
            mi.set_variant(variant)
        return mi
    if mi.variant() in MITSUBA_VARIANTS:
        return mi
    for variant in MITSUBA_VARIANTS:
        if variant in mi.variants():
            try:
                mi.set_variant(variant)
                mi.load_dict({"type": "diffuse"})
                return mi
            except Exception:  # noqa: BLE001 - an LLVM variant without libLLVM
                continue
    raise RuntimeError(f"none of the Mitsuba variants {MITSUBA_VARIANTS} runs here")


def mitsuba_eval(material: dict, wi: np.ndarray, wo: np.ndarray, chunk: int = 1 << 20):
    """f_r (n, 3) of the Mitsuba material ``material`` (a load_dict dictionary) at the
    direction pairs ``wi``, ``wo`` (n, 3), local frame, normal +z."""
    import drjit as dr

    mi = mitsuba()
    bsdf = mi.load_dict(material)
    ctx = mi.BSDFContext()
    wi = np.asarray(wi, np.float64)
    wo = np.asarray(wo, np.float64)
    out = np.zeros((wi.shape[0], 3))
    if mi.variant().startswith("scalar"):
        for j, (a, b) in enumerate(zip(wi, wo, strict=True)):
            si = mi.SurfaceInteraction3f()
            si.wi = mi.Vector3f(*a)
            out[j] = np.array(bsdf.eval(ctx, si, mi.Vector3f(*b)))
    else:
        for s in range(0, wi.shape[0], chunk):
            a, b = wi[s:s + chunk], wo[s:s + chunk]
            si = dr.zeros(mi.SurfaceInteraction3f, a.shape[0])
            si.wi = mi.Vector3f(a.T)
            out[s:s + chunk] = np.array(bsdf.eval(ctx, si, mi.Vector3f(b.T))).T
    cos_o = wo[:, 2:3]
    return np.where(cos_o > 0, out / np.where(cos_o > 0, cos_o, 1.0), 0.0)


def log_rmse(f_a: np.ndarray, f_b: np.ndarray, cos_i: np.ndarray, weight: np.ndarray) -> float:
    """``brdffit.fitting.loss``'s log_rmse of two (n, 3) BRDF arrays, bin weights ``weight``."""
    d = np.log1p(f_a * cos_i[:, None]) - np.log1p(f_b * cos_i[:, None])
    w = weight / weight.sum()
    return float(np.sqrt(np.sum(w[:, None] * d * d) / 3.0))


def mitsuba_log_rmse(material: dict, reference: np.ndarray) -> float:
    """log_rmse of the Mitsuba material against ``reference`` values (3, 90*90*180) on
    every bin above the horizon (e.g. ``conversion.fit_as_table(result).rgb``)."""
    g = bin_grid()
    idx = np.flatnonzero(g.above_horizon)
    f_mi = mitsuba_eval(material, g.wi[idx], g.wo[idx])
    ref = np.asarray(reference).reshape(3, -1)[:, idx].T
    return log_rmse(f_mi, ref, g.cos_i[idx], g.weight[idx])


def mitsuba_sphere(material: dict, light: np.ndarray, size: int = 128, spp: int = 64,
                   variant: str | None = None):
    """Radiance image (size, size, 3, linear sRGB) of the unit sphere with ``material``,
    rendered by Mitsuba's ``direct`` integrator: the camera and light of
    ``brdffit.fitting.sphere``. ``variant``: as :func:`mitsuba` (default an RGB one); in
    a spectral variant pass the material's spectral form
    (``brdffit.export.mitsuba.load_dict(params, spectral=True)``). The light is white
    in both: in a spectral variant its ``rgb`` irradiance becomes D65, which Mitsuba's
    film maps back to sRGB white (a white diffuse sphere renders the same mean colour
    in ``scalar_rgb`` and ``scalar_spectral``, tested)."""
    mi = mitsuba(variant)
    light = np.asarray(light, float) / np.linalg.norm(light)
    scene = mi.load_dict({
        "type": "scene",
        "integrator": {"type": "direct", "emitter_samples": 1, "bsdf_samples": 0},
        "sensor": {
            "type": "orthographic",
            # looking along -z from +z; x right, y up as in brdffit's sphere
            "to_world": mi.ScalarTransform4f().look_at(origin=[0, 0, 5], target=[0, 0, 0],
                                                       up=[0, 1, 0])
            @ mi.ScalarTransform4f().scale([1, 1, 1]),
            "film": {"type": "hdrfilm", "width": size, "height": size,
                     "rfilter": {"type": "box"}, "pixel_format": "rgb"},
            "sampler": {"type": "independent", "sample_count": spp},
        },
        "sphere": {"type": "sphere", "radius": 1.0, "bsdf": material},
        # irradiance pi on a surface facing the light, as brdffit's renders
        "light": {"type": "directional", "direction": (-light).tolist(),
                  "irradiance": {"type": "rgb", "value": [np.pi] * 3}},
    })
    return np.array(mi.render(scene), dtype=np.float64)[..., :3]


def materialx_validate(text: str) -> tuple[bool, str]:
    """MaterialX's own validation of a document, its standard libraries imported
    (every node must resolve to a node definition)."""
    mx = _import("MaterialX", "brdffit.export.validate.materialx_validate")
    doc = mx.createDocument()
    mx.readFromXmlString(doc, text)
    lib = mx.createDocument()
    mx.loadLibraries(mx.getDefaultDataLibraryFolders(), mx.getDefaultDataSearchPath(), lib)
    doc.importLibrary(lib)
    ok, message = doc.validate()
    unresolved = [n.getName() for n in doc.getNodes() if n.getNodeDef() is None]
    if unresolved:
        return False, f"{message}nodes without a node definition: {unresolved}"
    return bool(ok), message


_GLTF_SCRIPT = """
const validator = require(process.argv[1]);
const chunks = [];
process.stdin.on('data', c => chunks.push(c));
process.stdin.on('end', () => {
  validator.validateBytes(new Uint8Array(Buffer.concat(chunks)))
    .then(report => process.stdout.write(JSON.stringify(report)))
    .catch(err => { process.stderr.write(String(err)); process.exit(1); });
});
"""


def gltf_validate(document: dict, validator: str) -> dict:
    """The Khronos glTF validator's report (``issues.numErrors`` ...) of a glTF JSON
    document; ``validator``: the installed ``gltf-validator`` npm package's folder."""
    from brdffit import jsonout

    if shutil.which("node") is None:
        raise BrdffitError("the glTF check needs Node.js (node) and the npm package "
                           "gltf-validator")
    out = subprocess.run(["node", "-e", _GLTF_SCRIPT, validator],
                         input=jsonout.dumps(document).encode(), capture_output=True,
                         timeout=120, check=False)
    if out.returncode != 0:
        raise RuntimeError(f"gltf-validator failed: {out.stderr.decode()[-2000:]}")
    return json.loads(out.stdout)
