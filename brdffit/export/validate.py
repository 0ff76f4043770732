"""Checks of an export with the renderers' own tools: Mitsuba 3, MaterialX, the Khronos
glTF validator, three.js. Needs the ``export-check`` extra (and Node.js for glTF;
playwright and Chromium for three.js); fitting and exporting never do.

- :func:`mitsuba_eval` evaluates an exported Mitsuba material with Mitsuba itself
  (``BSDF.eval`` returns f_r cos_o; divided here, so it compares with a model's f_r);
- :func:`mitsuba_log_rmse` is the fidelity *measured in Mitsuba*: the loss of
  ``brdffit.fitting.loss`` between Mitsuba's values of the export and the fitted
  BRDF, on every bin above the horizon (the bins the export's reported
  ``log_rmse_to_fit`` is computed on);
- :func:`mitsuba_sphere` renders the unit sphere of ``brdffit.fitting.sphere`` (orthographic
  camera along -z, a directional light of irradiance pi) with Mitsuba's path tracer;
- :func:`materialx_validate`, :func:`gltf_validate`: the tools' own document checks;
- :func:`gltf_spec_eval`: glTF's BRDF as its spec writes it, independently of brdffit's
  model (no renderer here evaluates glTF's BRDF, so the spec is the reference);
- :func:`materialx_eval` evaluates a MaterialX document as MaterialX shades it: the
  GLSL its own generator writes (:func:`materialx_glsl`), run on a headless OpenGL 4
  context (moderngl on EGL; Mesa's llvmpipe where there is no GPU), divided by cos_i;
- :func:`threejs_render`: a glTF document (JSON or .glb) as three.js's GLTFLoader and
  WebGLRenderer show it, in headless Chromium (WebGL2 on SwiftShader), linear radiance;
- :func:`blender_import`: what Blender's own glTF importer makes of a file, and its
  Cycles render of the file's camera and lights.
"""

from __future__ import annotations

import base64
import importlib
import json
import shutil
import subprocess
import urllib.parse
from pathlib import Path

import numpy as np

from brdffit.errors import BrdffitError
from brdffit.export.gltf import VIEWER_MODELS
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


def gltf_spec_eval(p: dict, wi: np.ndarray, wo: np.ndarray, pseudocode: bool = False):
    """f_r (n, 3) of a glTF material (``base_color``, ``metallic``, ``roughness``,
    optionally KHR_materials_ior's ``ior``, KHR_materials_sheen's ``sheen_color`` and
    ``sheen_roughness`` (:func:`_sheen_over`), KHR_materials_iridescence's
    ``iridescence``, ``iridescence_ior`` and ``iridescence_thickness``
    (:func:`_iridescent`) and KHR_materials_clearcoat's ``clearcoat`` and
    ``clearcoat_roughness``) at direction pairs ``wi``, ``wo`` (n, 3)
    strictly above the horizon: glTF 2.0 Appendix B, term by term as the spec writes it
    (its V = G / (4 N.L N.V), G1(X) = 2 N.X / (N.X + sqrt(a^2 + (1 - a^2) (N.X)^2))): its
    definition, ``mix(dielectric_brdf, metal_brdf, metallic)`` with
    ``dielectric_brdf = fresnel_mix(ior, diffuse_brdf(base), specular_brdf)`` and
    ``metal_brdf = conductor_fresnel(base, specular_brdf)``, or with ``pseudocode`` its
    implementation pseudocode (one Fresnel from the lerped f0). Written from the spec's
    text in numpy, sharing no code with ``brdffit.models``: the independent evaluation
    the glTF model and export are checked against."""
    base, m, a = np.asarray(p["base_color"]), p["metallic"], p["roughness"] ** 2
    # KHR_materials_ior: the dielectric's f0 from its ior; the core spec's is 0.04
    dielectric_f0 = ((p["ior"] - 1) / (p["ior"] + 1)) ** 2 if "ior" in p else 0.04
    h = wi + wo
    h /= np.linalg.norm(h, axis=-1, keepdims=True)
    nl, nv, nh, vh = wi[:, 2:3], wo[:, 2:3], h[:, 2:3], np.sum(wo * h, -1, keepdims=True)
    d = a**2 / (np.pi * (nh**2 * (a**2 - 1) + 1) ** 2)

    def g1(x):
        return 2 * x / (x + np.sqrt(a**2 + (1 - a**2) * x**2))

    specular_brdf = g1(nl) * g1(nv) / (4 * nl * nv) * d
    diffuse_brdf = base / np.pi

    def schlick(f0):
        return f0 + (1 - f0) * (1 - np.abs(vh)) ** 5

    if pseudocode:
        fresnel = schlick(dielectric_f0 * (1 - m) + base * m)
        material = (1 - fresnel) * base * (1 - m) / np.pi + fresnel * specular_brdf
    else:
        fr = schlick(dielectric_f0)
        dielectric_brdf = diffuse_brdf * (1 - fr) + specular_brdf * fr  # mix(base, layer, fr)
        metal_brdf = specular_brdf * schlick(base)
        if p.get("iridescence"):
            dielectric_brdf, metal_brdf = _iridescent(p, dielectric_brdf, metal_brdf,
                                                      diffuse_brdf, specular_brdf, nv)
        material = dielectric_brdf * (1 - m) + metal_brdf * m
    if "sheen_color" in p:
        material = _sheen_over(material, p, nl, nv, nh)
    if not p.get("clearcoat"):
        return material
    # KHR_materials_clearcoat, "Implementation": the coat's normal is the surface's
    #   clearcoat_fresnel = 0.04 + (1 - 0.04) * (1 - abs(VdotNc))^5
    #   clearcoat_brdf = D(a_c) * G(a_c) / (4 * abs(VdotNc) * abs(LdotNc)), a_c = r_c^2
    #   coated_material = mix(material, clearcoat_brdf, clearcoat * clearcoat_fresnel)
    ac = p["clearcoat_roughness"] ** 2
    dc = ac**2 / (np.pi * (nh**2 * (ac**2 - 1) + 1) ** 2)

    def g1c(x):
        return 2 * x / (x + np.sqrt(ac**2 + (1 - ac**2) * x**2))

    clearcoat_brdf = dc * g1c(np.abs(nl)) * g1c(np.abs(nv)) / (4 * np.abs(nv) * np.abs(nl))
    clearcoat_fresnel = 0.04 + (1 - 0.04) * (1 - np.abs(nv)) ** 5
    weight = p["clearcoat"] * clearcoat_fresnel
    return material * (1 - weight) + clearcoat_brdf * weight


def _iridescent(p: dict, dielectric_brdf, metal_brdf, diffuse_brdf, specular_brdf, nv):
    """KHR_materials_iridescence's two BRDFs ("Implementation Notes"):
    ``iridescent_conductor_layer`` and ``iridescent_dielectric_layer`` (base ior 1.5),
    the film's Fresnel at "the viewing angle theta_1", ``nv``: the view's to the normal,
    as the extension's reference implementation reads it."""
    strength = p["iridescence"]
    film_ior, thickness = p["iridescence_ior"], p["iridescence_thickness"]
    base_f0 = ((1 - 1.5) / (1 + 1.5)) ** 2
    iridescent_f = _iridescent_fresnel(1.0, film_ior, np.full((len(nv), 3), base_f0),
                                       thickness, nv)
    rgb_alpha_max = iridescent_f.max(axis=-1, keepdims=True)
    rgb_mix = (1 - rgb_alpha_max) * diffuse_brdf + iridescent_f * specular_brdf
    dielectric = dielectric_brdf * (1 - strength) + rgb_mix * strength
    conductor_f = _iridescent_fresnel(
        1.0, film_ior, np.broadcast_to(np.asarray(p["base_color"], float), (len(nv), 3)),
        thickness, nv)
    metal = metal_brdf * (1 - strength) + specular_brdf * conductor_f * strength
    return dielectric, metal


def _iridescent_fresnel(outside_ior, film_ior, base_f0, thickness, cos_theta1):
    """``iridescent_fresnel`` (n, 3), the extension's GLSL in numpy, line by line; the
    base's f0 guarded as three.js does where the text's ``+ 0.0001`` overshoots 1."""

    def f_schlick(f0, cos):
        return f0 + (1 - f0) * (1 - cos) ** 5

    def ior_to_fresnel0(transmitted, incident):
        return ((transmitted - incident) / (transmitted + incident)) ** 2

    # first interface
    r0 = ior_to_fresnel0(film_ior, outside_ior)
    r12 = f_schlick(r0, cos_theta1)  # (n, 1)
    t121 = 1.0 - r12
    sin_theta2_sq = (outside_ior / film_ior) ** 2 * (1 - cos_theta1**2)
    cos_theta2 = np.sqrt(1 - sin_theta2_sq)  # no total internal reflection: film_ior > 1
    # second interface
    sqrt_f0 = np.sqrt(np.minimum(base_f0 + 0.0001, 0.9999))
    base_ior = (1 + sqrt_f0) / (1 - sqrt_f0)
    r1 = ior_to_fresnel0(base_ior, film_ior)
    r23 = f_schlick(r1, cos_theta2)
    phi12 = np.pi if film_ior < outside_ior else 0.0
    phi21 = np.pi - phi12
    phi23 = np.where(base_ior < film_ior, np.pi, 0.0)
    opd = 2 * film_ior * thickness * cos_theta2  # (n, 1)
    phi = phi21 + phi23
    # compound terms
    r123 = np.clip(r12 * r23, 1e-5, 0.9999)
    sqrt_r123 = np.sqrt(r123)
    rs = t121**2 * r23 / (1 - r123)
    intensity = r12 + rs
    cm = rs - t121
    for order in (1, 2):
        cm = cm * sqrt_r123
        intensity = intensity + cm * 2 * _eval_sensitivity(order * opd, order * phi)
    return np.maximum(intensity, 0.0)


def _eval_sensitivity(opd, shift):
    """``evalSensitivity``: (n, 3) linear Rec. 709 of optical path differences (n, 1) nm
    and phase shifts (n, 3), the shift's k-th component applied to X, Y, Z's k-th."""
    phase = 2 * np.pi * opd * 1.0e-9
    val = np.array([5.4856e-13, 4.4201e-13, 5.2481e-13])
    pos = np.array([1.6810e06, 1.7953e06, 2.2084e06])
    var = np.array([4.3278e09, 9.3046e09, 6.6121e09])
    xyz = val * np.sqrt(2 * np.pi * var) * np.cos(pos * phase + shift) * np.exp(-phase**2 * var)
    xyz[:, 0] += (9.7470e-14 * np.sqrt(2 * np.pi * 4.5282e09) * np.cos(2.2399e06 * phase[:, 0]
                  + shift[:, 0]) * np.exp(-4.5282e09 * phase[:, 0] ** 2))
    xyz /= 1.0685e-7
    # GLSL's mat3(...) is column-major: these rows are its columns
    xyz_to_rec709 = np.array([[3.2404542, -0.9692660, 0.0556434],
                              [-1.5371385, 1.8760108, -0.2040259],
                              [-0.4985314, 0.0415560, 1.0572252]]).T
    return xyz @ xyz_to_rec709.T


def _sheen_over(material, p: dict, nl, nv, nh):
    """KHR_materials_sheen's layering, ``f_sheen + material * sheenAlbedoScaling``, with
    the sheen BRDF three.js r187 writes (``BRDF_Sheen``, ``IBLSheenBRDF``,
    ``RE_Direct_Physical``), transcribed from its GLSL: the extension leaves the BRDF
    to the implementation."""
    color, r = np.asarray(p["sheen_color"], float), float(p["sheen_roughness"])
    alpha = r * r
    sin2h = np.maximum(1.0 - nh * nh, 0.0078125)
    d_charlie = (2.0 + 1.0 / alpha) * sin2h ** (0.5 / alpha) / (2.0 * np.pi)
    v_neubelt = np.clip(1.0 / (4.0 * (nl + nv - nl * nv)), 0.0, 1.0)

    def albedo(cos):  # IBLSheenBRDF
        r_inv = 1.0 / (r + 0.1)
        a = -1.9362 + 1.0678 * r + 0.4573 * r * r - 0.8469 * r_inv
        b = -0.6014 + 0.5538 * r - 0.4670 * r * r - 0.1255 * r_inv
        return np.clip(np.exp(a * np.clip(cos, 0, 1) + b), 0.0, 1.0)

    scaling = 1.0 - color.max() * np.maximum(albedo(nv), albedo(nl))
    return color * d_charlie * v_neubelt + material * scaling


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


# -- MaterialX's own shading: its generated GLSL, run on OpenGL ------------------------

#: The harness's vertex stage: one point per direction pair, at its own pixel, carrying
#: the generated pixel shader's ``VertexData`` (normal +z, the surface point at -wo so
#: that the shader's V = normalize(u_viewPosition - positionWorld) is wo).
_MTLX_VERTEX = """#version 400
in vec3 i_position;
in vec2 i_pixel;
out VertexData
{
    vec3 normalWorld;
    vec3 tangentWorld;
    vec3 positionWorld;
} vd;
void main()
{
    vd.normalWorld = vec3(0.0, 0.0, 1.0);
    vd.tangentWorld = vec3(1.0, 0.0, 0.0);
    vd.positionWorld = i_position;
    gl_Position = vec4(i_pixel, 0.0, 1.0);
    gl_PointSize = 1.0;
}
"""


def materialx_glsl(text: str) -> str:
    """The GLSL pixel shader MaterialX's own generator (``GlslShaderGenerator``, GLSL
    4.0) writes for the first surface shader node of the document ``text``: one
    directional light bound (``ND_directional_light``), no environment light
    (``SPECULAR_ENVIRONMENT_NONE``), no shadow map; every other option at its default
    (analytic directional albedo, no sRGB encoding, no transparency)."""
    who = "brdffit.export.validate.materialx_glsl"
    mx = _import("MaterialX", who)
    gen_shader = _import("MaterialX.PyMaterialXGenShader", who)
    gen_glsl = _import("MaterialX.PyMaterialXGenGlsl", who)
    doc = mx.createDocument()
    mx.readFromXmlString(doc, text)
    lib = mx.createDocument()
    mx.loadLibraries(mx.getDefaultDataLibraryFolders(), mx.getDefaultDataSearchPath(), lib)
    doc.importLibrary(lib)
    shaders = [n for n in doc.getNodes() if n.getType() == "surfaceshader"]
    if not shaders:
        raise ValueError("the document has no surface shader node")
    gen = gen_glsl.GlslShaderGenerator.create()
    ctx = gen_shader.GenContext(gen)
    ctx.registerSourceCodeSearchPath(mx.getDefaultDataSearchPath())
    opt = ctx.getOptions()
    methods = gen_shader.HwSpecularEnvironmentMethod
    opt.hwSpecularEnvironmentMethod = methods.SPECULAR_ENVIRONMENT_NONE
    opt.hwShadowMap = False
    opt.hwMaxActiveLightSources = 1
    gen_shader.HwShaderGenerator.bindLightShader(doc.getNodeDef("ND_directional_light"), 1, ctx)
    shader = gen.generate("brdffit", shaders[0], ctx)
    source = shader.getSourceCode(gen_shader.PIXEL_STAGE)
    if "uniform bool u_refractionTwoSided" not in source:
        # MaterialX 1.39.5 declares this transmission option only with an environment
        # method, but its mx_environment_none.glsl reads it; false is its default
        source = source.replace("uniform int u_numActiveLightSources",
                                "uniform bool u_refractionTwoSided = false;\n"
                                "uniform int u_numActiveLightSources", 1)
    return source


def materialx_eval(text: str, wi: np.ndarray, wo: np.ndarray) -> np.ndarray:
    """f_r (n, 3) of the MaterialX document ``text`` as MaterialX's generated GLSL shades
    it (:func:`materialx_glsl`), run on an OpenGL 4 context without a display (moderngl,
    EGL; Mesa's llvmpipe where there is no GPU), at the direction pairs ``wi`` (light),
    ``wo`` (view), local frame, normal +z.

    Each pair is one point drawn with a directional light of colour 1 and intensity 1
    from ``wi``; the shader writes ``sum over lights of intensity * response``, and a
    BSDF's response is f_r cos_i, so the value read back is divided by cos_i
    (MaterialX's clamp to [1e-8, 1]). Single precision, as the shader.
    """
    moderngl = _import("moderngl", "brdffit.export.validate.materialx_eval")
    wi = np.asarray(wi, np.float64).reshape(-1, 3)
    wo = np.asarray(wo, np.float64).reshape(-1, 3)
    n = wi.shape[0]
    width = min(n, 1024)
    height = -(-n // width)
    j = np.arange(n)
    pixel = np.stack([(2 * (j % width) + 1) / width - 1, (2 * (j // width) + 1) / height - 1], -1)
    ctx = moderngl.create_standalone_context(backend="egl", require=400)
    try:
        prog = ctx.program(vertex_shader=_MTLX_VERTEX, fragment_shader=materialx_glsl(text))
        target = ctx.renderbuffer((width, height), components=4, dtype="f4")
        fbo = ctx.framebuffer(color_attachments=[target])
        fbo.use()
        fbo.clear(0.0, 0.0, 0.0, 0.0)
        ctx.disable(moderngl.BLEND | moderngl.DEPTH_TEST | moderngl.CULL_FACE)
        data = np.hstack([-wo, pixel]).astype("f4")
        vbo = ctx.buffer(reserve=data.nbytes)
        vao = ctx.vertex_array(prog, [(vbo, "3f 2f", "i_position", "i_pixel")])
        prog["u_viewPosition"].value = (0.0, 0.0, 0.0)
        prog["u_numActiveLightSources"].value = 1
        prog["u_lightData[0].type"].value = 1
        prog["u_lightData[0].color"].value = (1.0, 1.0, 1.0)
        prog["u_lightData[0].intensity"].value = 1.0
        # one draw per distinct light direction
        lights, inverse = np.unique(wi, axis=0, return_inverse=True)
        order = np.argsort(inverse.ravel(), kind="stable")
        counts = np.bincount(inverse.ravel(), minlength=len(lights))
        starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
        vbo.write(data[order].tobytes())
        for light, first, count in zip(lights, starts, counts, strict=True):
            prog["u_lightData[0].direction"].value = tuple(float(x) for x in -light)
            vao.render(moderngl.POINTS, vertices=int(count), first=int(first))
        raw = np.frombuffer(fbo.read(components=4, dtype="f4"), np.float32)
        # each point carries its own pair's pixel, whatever its place in the buffer
        out = raw.reshape(height, width, 4)[..., :3].reshape(-1, 3)[:n].astype(np.float64)
    finally:
        ctx.release()
    return out / np.clip(wi[:, 2:3], 1e-8, 1.0)


# -- three.js: a glTF document as a web viewer shows it --------------------------------

#: Chromium without a GPU: WebGL2 on SwiftShader (software Vulkan) through ANGLE.
#: Upstream Chromium no longer falls back to SwiftShader for WebGL by itself, hence
#: ``--enable-unsafe-swiftshader`` (Debian's 156 still does, and playwright passes that
#: flag too: said here so as not to depend on either); the rest keep the browser off
#: the network.
THREEJS_CHROMIUM_ARGS = (
    "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
    "--disable-background-networking", "--disable-component-update", "--disable-sync",
    "--use-gl=angle", "--use-angle=swiftshader", "--enable-unsafe-swiftshader",
)

#: The page's origin: never resolved, every request to it is answered by playwright
#: (``page.route``), so nothing listens on any port and nothing leaves the machine.
_THREEJS_ORIGIN = "http://brdffit-threejs.invalid"
_THREEJS_TIMEOUT_S = 120

#: The page renders on load and leaves ``window.result``: ``{pixels}`` (the float
#: RGBA render target, bottom row first, base64) or ``{error}``. A classic script with
#: dynamic imports, so that a module that fails to load is an error it catches.
_THREEJS_PAGE = """<!DOCTYPE html>
<html><head><meta charset="utf-8"><link rel="icon" href="data:,">
<script type="importmap">
{"imports": {"three": "/three/build/three.module.js", "three/addons/": "/three/examples/jsm/"}}
</script>
<script>
async function render(size) {
  const THREE = await import('three');
  const {GLTFLoader} = await import('three/addons/loaders/GLTFLoader.js');
  const context = document.createElement('canvas').getContext('webgl2');
  if (context === null) throw new Error('this browser has no WebGL2');
  const renderer = new THREE.WebGLRenderer({canvas: context.canvas, context,
                                            antialias: false, preserveDrawingBuffer: true});
  // float colour buffers: the radiance as the shader writes it, unclamped
  if (!renderer.extensions.has('EXT_color_buffer_float'))
    throw new Error('this WebGL2 cannot render to float targets (EXT_color_buffer_float)');
  renderer.toneMapping = THREE.NoToneMapping;
  renderer.setClearColor(0x000000, 0);
  // a render target's colour space is linear: no sRGB encoding on output
  const target = new THREE.WebGLRenderTarget(size, size, {type: THREE.FloatType});

  const data = await (await fetch('/document')).arrayBuffer();
  const gltf = await new GLTFLoader().parseAsync(data, '');
  const scene = new THREE.Scene();
  scene.background = null;
  if (gltf.scene !== undefined) scene.add(gltf.scene);  // a document may have no scene

  let camera = gltf.cameras[0];
  if (camera === undefined) {
    camera = new THREE.PerspectiveCamera(50, 1, 0.1, 100);
    camera.position.set(0, 0, 3);
    camera.lookAt(0, 0, 0);
  } else if (camera.isPerspectiveCamera) {
    camera.aspect = 1;
    camera.updateProjectionMatrix();
  }
  let lit = false;
  scene.traverse(o => { lit = lit || o.isLight === true; });
  if (!lit) {
    // irradiance pi on a surface facing it, as brdffit's own renders
    const light = new THREE.DirectionalLight(0xffffff, Math.PI);
    light.position.set(-0.5, 0.5, 0.7071);  // shining towards its target, the origin
    scene.add(light);
  }

  renderer.setRenderTarget(target);
  renderer.render(scene, camera);
  const pixels = new Float32Array(size * size * 4);
  renderer.readRenderTargetPixels(target, 0, 0, size, size, pixels);
  const bytes = new Uint8Array(pixels.buffer);
  let text = '';
  for (let i = 0; i < bytes.length; i += 0x8000)
    text += String.fromCharCode(...bytes.subarray(i, i + 0x8000));
  return btoa(text);
}
render(%(size)d).then(pixels => { window.result = {pixels}; },
                      e => { window.result = {error: String(e && e.stack || e)}; });
</script></head><body></body></html>
"""


def threejs_render(document: dict | bytes, threejs: str, size: int = 256,
                   chromium: str | None = None) -> np.ndarray:
    """The image (size, size, 4: linear RGBA, float32, rows top to bottom) three.js
    renders of a glTF 2.0 ``document``: a JSON document (its buffers embedded as data:
    URIs) or the bytes of a .glb. ``threejs``: the installed npm package ``three``'s
    folder (``.../node_modules/three``); ``chromium``: the browser (default
    ``/usr/bin/chromium``), run headless by playwright with WebGL2 on SwiftShader.

    three.js's ``GLTFLoader`` loads the document; ``WebGLRenderer`` (no antialiasing,
    no tone mapping) draws it into a float render target, read back as it is: linear
    radiance, unclamped, not sRGB encoded. The camera is the document's first one
    (aspect 1), else a perspective one (fov 50 degrees) at (0, 0, 3) looking at the
    origin; the lights are the document's (KHR_lights_punctual), else one directional
    light of intensity pi from (-0.5, 0.5, 0.7071). The background is (0, 0, 0, 0).

    Raises BrdffitError with the page's message when the page fails (no WebGL2 or no
    float render targets, a loader error, an exception) or logs an error (three.js
    reports a shader that fails to compile, or a target it cannot read, only so).
    Served by playwright's request interception; the browser makes no other request.
    """
    from brdffit import jsonout

    try:
        from playwright.sync_api import Error as PlaywrightError
        from playwright.sync_api import sync_playwright
    except ModuleNotFoundError:  # playwright is in the test extra, not export-check
        raise MissingExtraError("brdffit.export.validate.threejs_render", "test",
                                ("playwright",)) from None

    root = Path(threejs).resolve()
    if not (root / "build" / "three.module.js").is_file():
        raise BrdffitError(f"{threejs} is not the npm package three (no build/three.module.js)")
    data = document if isinstance(document, bytes) else jsonout.dumps(document).encode()
    page_html = _THREEJS_PAGE % {"size": size}

    def serve(route):
        url = urllib.parse.urlsplit(route.request.url)
        if f"{url.scheme}://{url.netloc}" != _THREEJS_ORIGIN:
            route.abort()  # the document's external resources included: it must embed them
        elif url.path == "/":
            route.fulfill(body=page_html, content_type="text/html")
        elif url.path == "/document":
            route.fulfill(body=data, content_type="application/octet-stream")
        else:
            file = (root / url.path.removeprefix("/three/")).resolve()
            if url.path.startswith("/three/") and file.is_relative_to(root) and file.is_file():
                route.fulfill(path=file, content_type="text/javascript")
            else:
                route.fulfill(status=404)

    problems = []
    timeout_ms = _THREEJS_TIMEOUT_S * 1000
    try:
        with sync_playwright() as p:
            browser = p.chromium.launch(executable_path=chromium or "/usr/bin/chromium",
                                        args=list(THREEJS_CHROMIUM_ARGS), timeout=timeout_ms)
            try:
                page = browser.new_page()
                page.on("pageerror", lambda e: problems.append(str(e)))
                page.on("console",
                        lambda m: problems.append(m.text) if m.type == "error" else None)
                page.route("**/*", serve)
                page.goto(_THREEJS_ORIGIN + "/", timeout=timeout_ms)
                page.wait_for_function("() => window.result !== undefined", timeout=timeout_ms)
                result = page.evaluate("() => window.result")
            finally:
                browser.close()
    except PlaywrightError as e:  # no browser, or a page that timed out
        raise BrdffitError(f"three.js render failed: {e}") from None
    if "error" in result or problems:
        raise BrdffitError("three.js render failed: "
                           + "\n".join([result.get("error", "")] + problems).strip())
    pixels = np.frombuffer(base64.b64decode(result["pixels"]), np.float32)
    return pixels.reshape(size, size, 4)[::-1].copy()  # WebGL's rows run bottom-up


def gltf_preview_pairs(size: int):
    """What each pixel of a ``size`` x ``size`` render of an exported glTF file sees
    through the file's own camera and light (``brdffit.export.gltf``), flat, row by row
    from the top: the (wi, wo) pair in the unit sphere's local frame (each (n, 3)),
    whether the pixel sees the sphere, and three.js's screen-space roughness term there
    (the normal's change to the next pixel, ``geometryRoughness``). For comparing a
    viewer's render with a model of its shading pixel by pixel."""
    from brdffit.export import gltf
    from brdffit.io.angles import tangent_frames

    t = np.tan(gltf.CAMERA_YFOV / 2)
    c = (np.arange(size) + 0.5) / size * 2 - 1
    x, y = np.meshgrid(c * t, -c * t)
    ray = np.stack([x, y, -np.ones_like(x)], -1)
    ray /= np.linalg.norm(ray, axis=-1, keepdims=True)
    eye = np.array([0.0, 0.0, gltf.CAMERA_DISTANCE])
    b = ray @ eye
    disc = b * b - (eye @ eye - 1.0)
    point = eye + (-b - np.sqrt(np.maximum(disc, 0.0)))[..., None] * ray
    normal = point / np.linalg.norm(point, axis=-1, keepdims=True)
    step = np.maximum(np.abs(np.diff(normal, axis=1, append=normal[:, -1:])),
                      np.abs(np.diff(normal, axis=0, append=normal[-1:])))
    light = np.array(gltf.PREVIEW_LIGHT_FROM) / np.linalg.norm(gltf.PREVIEW_LIGHT_FROM)
    frames = tangent_frames(normal)
    wi = (frames @ light).reshape(-1, 3)
    wo = np.einsum("...ij,...j->...i", frames, -ray).reshape(-1, 3)
    return wi, wo, (disc > 0).ravel(), step.max(-1).ravel()


def preview_radiance(model_name: str, params: dict, size: int) -> np.ndarray:
    """Each pixel's radiance (n, 3, row by row from the top) of an exported glTF
    file's preview scene, as ``model_name`` shades the file's ``params``: what a
    viewer of that shading renders (:func:`gltf_preview_pairs`; three.js's models with
    its per-pixel roughness term, ``screen_roughness``)."""
    import jax.numpy as jnp

    from brdffit import models, runtime
    from brdffit.models.frame import shading_frame
    from brdffit.models.gltf_threejs import screen_roughness

    wi, wo, _, step = gltf_preview_pairs(size)
    with runtime.float64():
        p = {k: jnp.asarray(v, dtype=jnp.float64) for k, v in params.items()}
        if model_name in VIEWER_MODELS["threejs"]:  # the base's and coat's, not the sheen's
            for name in ("roughness", "clearcoat_roughness"):
                if name in p:
                    p[name] = screen_roughness(p[name], jnp.asarray(step))
        f = np.asarray(models.get(model_name).eval_frame(
            p, shading_frame(jnp.asarray(wi), jnp.asarray(wo))))
    return f * np.pi * np.clip(wi[:, 2:3], 0.0, None)


#: What Blender's glTF importer made of a file, and its Cycles render (run inside
#: Blender: ``blender --background --factory-startup --python-expr``).
_BLENDER_SCRIPT = r"""
import array, json, sys, bpy
try:  # Debian 12's Blender 3.4 importer still says np.bool, which its numpy 1.24 removed
    import numpy
    if not hasattr(numpy, "bool"):
        numpy.bool = bool
except ImportError:
    pass
args = json.loads(sys.argv[sys.argv.index("--") + 1])
bpy.ops.wm.read_factory_settings(use_empty=True)
# COMPAT: a directional light's intensity is the sun's strength, the irradiance it
# gives (SPEC, the default, divides lux by 683 lm/W: a physically dim scene)
bpy.ops.import_scene.gltf(filepath=args["path"], convert_lighting_mode="COMPAT")
out = {"objects": [], "materials": {}}
for ob in bpy.context.scene.objects:
    out["objects"].append({"name": ob.name, "type": ob.type,
                           "materials": [s.material.name for s in ob.material_slots
                                         if s.material is not None]})
for mat in bpy.data.materials:
    inputs = {}
    node = next((n for n in (mat.node_tree.nodes if mat.use_nodes else [])
                 if n.type == "BSDF_PRINCIPLED"), None)
    if node is not None:
        for name in ("Base Color", "Metallic", "Roughness", "Specular", "IOR"):
            value = node.inputs[name].default_value
            inputs[name] = list(value) if hasattr(value, "__len__") else float(value)
    out["materials"][mat.name] = {"principled": inputs}
scene = bpy.context.scene
if scene.camera is None:  # the importer makes the file's camera, not the scene's
    scene.camera = next((ob for ob in scene.objects if ob.type == "CAMERA"), None)
if args["size"] and scene.camera is not None:
    scene.render.engine = "CYCLES"
    scene.cycles.device = "CPU"
    scene.cycles.samples = args["samples"]
    scene.cycles.use_denoising = False  # Debian's build has no OpenImageDenoise
    # each pixel's own radiance, as the models' previews give it: Cycles' default
    # 1.5-px filter spread a sharp highlight over its neighbours (a filmed plastic's
    # RMS log error against its table: 0.0363 filtered, 0.0033 unfiltered; the model 0.0034)
    scene.cycles.filter_width = 0.01
    scene.render.resolution_x = scene.render.resolution_y = args["size"]
    scene.render.resolution_percentage = 100
    scene.render.film_transparent = True
    scene.view_settings.view_transform = "Standard"
    scene.render.image_settings.file_format = "OPEN_EXR"
    scene.render.filepath = args["image"]
    bpy.ops.render.render(write_still=True)
    image = bpy.data.images.load(args["image"])
    pixels = array.array("f", bytes(4 * len(image.pixels)))
    image.pixels.foreach_get(pixels)
    with open(args["image"] + ".f32", "wb") as f:  # Blender's Python has no numpy
        pixels.tofile(f)
print("BRDFFIT-BLENDER " + json.dumps(out))
"""


def blender_import(path: str | Path, size: int = 0, samples: int = 16,
                   blender: str = "blender", timeout_s: float = 300) -> dict:
    """What Blender's own glTF importer makes of the file at ``path`` (.gltf or .glb):
    ``{"objects": [{"name", "type", "materials"}], "materials": {name: {"principled":
    {input: value}}}}`` (the Principled BSDF's Base Color, Metallic, Roughness,
    Specular and IOR as the importer set them), and with ``size`` > 0 ``"image"``: the
    file's own camera and lights rendered by Cycles on the CPU (size x size, linear
    RGBA, rows top to bottom; ``samples`` per pixel; each pixel its own radiance, the
    reconstruction filter narrowed to 0.01 px). ``blender``: the executable
    (Debian's package ``blender``). Raises BrdffitError where Blender is missing or
    the import fails."""
    import tempfile

    exe = shutil.which(blender)
    if exe is None:
        raise BrdffitError(f"Blender ({blender}) is not installed (Debian: apt-get install "
                           "blender)")
    with tempfile.TemporaryDirectory() as tmp:
        image = str(Path(tmp) / "render.exr")
        args = json.dumps({"path": str(Path(path).resolve()), "size": size,
                           "samples": samples, "image": image})
        run = subprocess.run([exe, "--background", "--factory-startup", "--python-expr",
                              _BLENDER_SCRIPT, "--", args], capture_output=True, text=True,
                             timeout=timeout_s)
        line = next((s for s in run.stdout.splitlines() if s.startswith("BRDFFIT-BLENDER ")),
                    None)
        if run.returncode != 0 or line is None:
            raise BrdffitError("Blender's glTF import failed: "
                               + (run.stdout + run.stderr)[-2000:].strip())
        out = json.loads(line.removeprefix("BRDFFIT-BLENDER "))
        if size:  # Blender's rows run bottom-up
            pixels = np.fromfile(image + ".f32", np.float32).reshape(size, size, 4)
            out["image"] = pixels[::-1].copy()
    return out
