"""glTF 2.0 export: a material of the core metallic-roughness model, in a glTF document.

Target model ``gltf_pbr`` (docs/models.md), the BRDF of the glTF 2.0 spec's
Appendix B, so the mapping is a copy:

    pbrMetallicRoughness.baseColorFactor = [base_color R, G, B, 1]
    pbrMetallicRoughness.metallicFactor  = metallic
    pbrMetallicRoughness.roughnessFactor = roughness          (the spec's alpha = roughness^2)

A ``gltf_clearcoat`` fit also writes ``KHR_materials_clearcoat`` (``clearcoatFactor``,
``clearcoatRoughnessFactor``: the model is the extension's definition, so the mapping is
a copy too), and a ``gltf_sheen`` fit ``KHR_materials_sheen`` (``sheenColorFactor``,
``sheenRoughnessFactor``, copied; the sheen's BRDF is three.js's, the extension leaving
it to the viewer), and a ``gltf_iridescence`` fit ``KHR_materials_iridescence``
(``iridescenceFactor``, ``iridescenceIor``, and the thickness as both
``iridescenceThicknessMinimum`` and ``Maximum``, copied). A ``gltf_pbr_ior`` fit also
writes the extension ``KHR_materials_ior`` (``{"ior": ior}``, listed in
``extensionsUsed``), which carries the dielectric's reflectance
``((ior - 1)/(ior + 1))^2``; a ``gltf_pbr`` fit is the spec's default (ior 1.5, f0 =
0.04, white specular), which ``KHR_materials_ior`` and ``KHR_materials_specular``
would only restate, so neither is written. Other fits are
converted to the core ``gltf_pbr`` (every viewer shades it), their loss reported.

The document is a file a viewer opens and shows: the material (still ``materials[0]``,
by its name) on a preview scene of a unit sphere (a UV sphere, positions and normals
in one embedded buffer), a perspective camera looking at it along -z, and a
directional light (``KHR_lights_punctual``) from the key light of brdffit's sphere
plots, 45 deg above-left, of 3.14 lux: irradiance pi, so that a white Lambertian
surface facing it has radiance 1, as in ``brdffit.fitting.sphere``. A document with
the material alone opened empty in three.js, and Blender's importer made no material
from it. :func:`to_glb` packs the document as a binary ``.glb``.
"""

from __future__ import annotations

import base64
import json
import math
import struct

import numpy as np

#: The models this target shades exactly; other fits are refitted as the first, or as
#: the one layered over it that keeps the fit's layers (``export._by_layers_kept``).
#: ``gltf_threejs`` and ``gltf_blender`` carry the same factors, fitted for three.js's or
#: Blender's shading (``viewer="threejs"``, ``viewer="blender"``).
TARGET_MODELS = ("gltf_pbr", "gltf_pbr_ior", "gltf_threejs", "gltf_blender", "gltf_clearcoat",
                 "gltf_threejs_clearcoat", "gltf_sheen", "gltf_threejs_sheen",
                 "gltf_blender_clearcoat", "gltf_blender_sheen", "gltf_iridescence",
                 "gltf_threejs_iridescence")
#: target model -> the model that evaluates the file as it is meant to be shaded: the
#: spec's definition (gltf_pbr, tests/test_target_models.py), or three.js's shading
SHADED_AS = {m: m for m in TARGET_MODELS}
#: viewer -> the models that shade a file as that viewer does, by the factors the file
#: carries (``fidelity.viewers`` takes the one whose parameters are the file's; with
#: none, that viewer's shading of the file is not modelled, and reported null). The
#: spec's definition takes in the extensions that define their BRDF (KHR_materials_ior,
#: _clearcoat, _iridescence: each of those models is its extension's text); a
#: KHR_materials_sheen file has none (the extension leaves the sheen to the viewer).
#: three.js's coat, sheen and film are ``gltf_threejs_clearcoat``, ``_sheen`` and
#: ``_iridescence`` (each over three.js's own base), Blender's coat and sheen (a Velvet
#: BSDF its importer adds) ``gltf_blender_clearcoat`` and ``gltf_blender_sheen``.
#: three.js's are checked against three.js itself (tests/test_export_viewers.py),
#: Blender's against its Cycles render (tests/test_export_blender.py).
VIEWER_MODELS = {"spec": ("gltf_pbr", "gltf_pbr_ior", "gltf_clearcoat", "gltf_iridescence"),
                 "threejs": ("gltf_threejs", "gltf_threejs_clearcoat", "gltf_threejs_sheen",
                             "gltf_threejs_iridescence"),
                 "blender": ("gltf_blender", "gltf_blender_clearcoat", "gltf_blender_sheen")}
#: viewer -> the model that shades the core factors as that viewer does: the target
#: model of an export made for it (``export(..., viewer=)``).
VIEWERS = {viewer: names[0] for viewer, names in VIEWER_MODELS.items()}
#: viewer -> the factors its importer ignores: Blender 3.4's shades a KHR_materials_ior
#: file at its Specular 0.5, an index of 1.5, and does not read KHR_materials_iridescence
#: (Principled v1 has no film): it shades such a file's base alone
#: (tests/test_export_blender.py).
VIEWER_IGNORES = {"blender": ("ior", "iridescence", "iridescence_ior",
                              "iridescence_thickness")}
MEDIA_TYPE = "model/gltf+json"
IOR_EXTENSION = "KHR_materials_ior"
IOR_NOTE = ("uses KHR_materials_ior: a viewer without the extension shades the dielectric "
            "with ior 1.5 (f0 0.04) instead")
CLEARCOAT_EXTENSION = "KHR_materials_clearcoat"
CLEARCOAT_NOTE = ("uses KHR_materials_clearcoat: a viewer without the extension shades the "
                  "base without its coat")
SHEEN_EXTENSION = "KHR_materials_sheen"
SHEEN_NOTE = ("uses KHR_materials_sheen: a viewer without the extension shades the base "
              "without its sheen; viewers with it may shade the sheen differently (the "
              "extension leaves its BRDF to them; gltf_sheen's is three.js's)")
IRIDESCENCE_EXTENSION = "KHR_materials_iridescence"
IRIDESCENCE_NOTE = ("uses KHR_materials_iridescence: a viewer without the extension shades the "
                    "base without its thin film")

#: The material extensions a fit's parameters call for, in the order they are written:
#: (extension, the parameter that calls for it, its object from the parameters (the
#: factors copied: each model is its extension's definition), the export's note).
_EXTENSIONS = (
    (IOR_EXTENSION, "ior", lambda p: {"ior": float(p["ior"])}, IOR_NOTE),
    (SHEEN_EXTENSION, "sheen_color", lambda p: {
        "sheenColorFactor": [float(x) for x in p["sheen_color"]],
        "sheenRoughnessFactor": float(p["sheen_roughness"])}, SHEEN_NOTE),
    # no thickness texture: the film is iridescenceThicknessMaximum thick everywhere;
    # the minimum is written equal, so that a texture added later keeps the thickness
    (IRIDESCENCE_EXTENSION, "iridescence", lambda p: {
        "iridescenceFactor": float(p["iridescence"]),
        "iridescenceIor": float(p["iridescence_ior"]),
        "iridescenceThicknessMinimum": float(p["iridescence_thickness"]),
        "iridescenceThicknessMaximum": float(p["iridescence_thickness"])}, IRIDESCENCE_NOTE),
    (CLEARCOAT_EXTENSION, "clearcoat", lambda p: {
        "clearcoatFactor": float(p["clearcoat"]),
        "clearcoatRoughnessFactor": float(p["clearcoat_roughness"])}, CLEARCOAT_NOTE),
)


def _extensions(params: dict) -> list[tuple]:
    """The rows of :data:`_EXTENSIONS` that ``params`` call for."""
    return [row for row in _EXTENSIONS if row[1] in params]


def material(params: dict, name: str) -> dict:
    """The glTF material object of ``gltf_pbr`` (``gltf_pbr_ior``, ``gltf_clearcoat``,
    ``gltf_sheen``, ``gltf_iridescence``) parameters."""
    out = {
        "name": name,
        "pbrMetallicRoughness": {
            "baseColorFactor": [*(float(x) for x in params["base_color"]), 1.0],
            "metallicFactor": float(params["metallic"]),
            "roughnessFactor": float(params["roughness"]),
        },
    }
    extensions = {name: factors(params) for name, _, factors, _ in _extensions(params)}
    if extensions:
        out["extensions"] = extensions
    return out


LIGHTS_EXTENSION = "KHR_lights_punctual"
#: Where the preview's light comes from (camera space: x right, y up, z towards the
#: viewer): the key light of brdffit's sphere plots (``brdffit.fitting.sphere.LIGHTS``).
PREVIEW_LIGHT_FROM = (-0.5, 0.5, 0.7071)
#: The light's illuminance (lux): irradiance pi, a white Lambertian surface facing the
#: light at radiance 1 (three.js and the glTF spec: radiance = f * E * cos).
PREVIEW_LUX = math.pi
#: The camera's distance from the sphere's centre and its vertical field of view: the
#: sphere fills ~80% of the frame's height.
CAMERA_DISTANCE = 4.0
CAMERA_YFOV = 2.0 * math.asin(1.0 / CAMERA_DISTANCE) / 0.8
#: The UV sphere's segments around and rings from pole to pole: smooth at 256 px.
SEGMENTS, RINGS = 64, 32


def document(params: dict, name: str) -> dict:
    """A glTF 2.0 JSON document: the one material on the preview scene (module
    docstring), every buffer embedded as a ``data:`` URI."""
    used = [LIGHTS_EXTENSION, *(name for name, *_ in _extensions(params))]
    blob, accessors, views = _sphere_buffers()
    return {
        "asset": {"version": "2.0", "generator": "brdffit"},
        "extensionsUsed": used,
        "scene": 0,
        "scenes": [{"name": f"{name} preview", "nodes": [0, 1, 2]}],
        "nodes": [
            {"name": f"{name} sphere", "mesh": 0},
            {"name": "camera", "camera": 0, "translation": [0.0, 0.0, CAMERA_DISTANCE]},
            {"name": "key light", "rotation": _pointing(PREVIEW_LIGHT_FROM),
             "extensions": {LIGHTS_EXTENSION: {"light": 0}}},
        ],
        "meshes": [{"name": f"{name} sphere", "primitives": [{
            "attributes": {"POSITION": 0, "NORMAL": 1}, "indices": 2, "material": 0}]}],
        "materials": [material(params, name)],
        "cameras": [{"type": "perspective", "name": "camera", "perspective": {
            "yfov": CAMERA_YFOV, "znear": 0.1, "zfar": 100.0}}],
        "extensions": {LIGHTS_EXTENSION: {"lights": [{
            "name": "key light", "type": "directional", "color": [1.0, 1.0, 1.0],
            "intensity": PREVIEW_LUX}]}},
        "accessors": accessors,
        "bufferViews": views,
        "buffers": [{"byteLength": len(blob), "uri": "data:application/octet-stream;base64,"
                     + base64.b64encode(blob).decode("ascii")}],
    }


def _pointing(source) -> list[float]:
    """The rotation (x, y, z, w) that turns a glTF light's -z (where it shines) away
    from ``source``, the direction the light comes from."""
    d = -np.asarray(source, float) / np.linalg.norm(source)
    z = np.array([0.0, 0.0, -1.0])
    axis = np.cross(z, d)
    q = np.array([*axis, 1.0 + float(z @ d)])
    return [float(x) for x in q / np.linalg.norm(q)]


def _sphere_buffers() -> tuple[bytes, list[dict], list[dict]]:
    """A unit UV sphere: (buffer bytes, accessors [POSITION, NORMAL, indices], their
    buffer views). On a unit sphere the normal is the position."""
    theta = np.linspace(0.0, np.pi, RINGS + 1)[:, None]  # from +y, the pole
    phi = np.linspace(0.0, 2 * np.pi, SEGMENTS + 1)[None, :]
    pos = np.stack(np.broadcast_arrays(np.sin(theta) * np.sin(phi), np.cos(theta),
                                       np.sin(theta) * np.cos(phi)), axis=-1)
    pos = pos.reshape(-1, 3).astype("<f4")
    i, j = np.meshgrid(np.arange(RINGS), np.arange(SEGMENTS), indexing="ij")
    a = i * (SEGMENTS + 1) + j  # a quad's corners: a, a+1 on this ring, b, b+1 below
    b = a + SEGMENTS + 1
    quads = np.stack([a, b, a + 1, a + 1, b, b + 1], axis=-1)  # counter-clockwise outside
    # the poles' quads are triangles: drop the one of zero area
    tris = np.concatenate([quads[1:, :, :3].reshape(-1, 3), quads[:-1, :, 3:].reshape(-1, 3)])
    idx = tris.astype("<u2").ravel()
    n_vert = len(pos)
    parts = [pos.tobytes(), pos.tobytes(), idx.tobytes()]
    views, offset = [], 0
    for data, target in zip(parts, (34962, 34962, 34963), strict=True):
        views.append({"buffer": 0, "byteOffset": offset, "byteLength": len(data),
                      "target": target})
        offset += (len(data) + 3) // 4 * 4  # each view 4-byte aligned
    blob = b"".join(p + b"\0" * ((-len(p)) % 4) for p in parts)
    lo, hi = pos.min(axis=0).tolist(), pos.max(axis=0).tolist()
    accessors = [
        {"bufferView": 0, "componentType": 5126, "count": n_vert, "type": "VEC3",
         "min": lo, "max": hi},
        {"bufferView": 1, "componentType": 5126, "count": n_vert, "type": "VEC3"},
        {"bufferView": 2, "componentType": 5123, "count": len(idx), "type": "SCALAR"},
    ]
    return blob, accessors, views


def to_glb(document: dict) -> bytes:
    """The document as a binary glTF (``.glb``): its one embedded buffer moved into
    the BIN chunk (glTF 2.0, section 4.4)."""
    doc = json.loads(json.dumps(document))  # a copy: the caller's stays as it is
    (buffer,) = doc["buffers"]
    blob = base64.b64decode(buffer.pop("uri").split(",", 1)[1])
    blob += b"\0" * ((-len(blob)) % 4)
    text = json.dumps(doc, separators=(",", ":")).encode()
    text += b" " * ((-len(text)) % 4)
    chunks = (struct.pack("<I4s", len(text), b"JSON") + text
              + struct.pack("<I4s", len(blob), b"BIN\0") + blob)
    return struct.pack("<4sII", b"glTF", 2, 12 + len(chunks)) + chunks


def write(params: dict, name: str, target_model: str) -> tuple[dict, dict[str, str], list[str]]:
    """The material (the glTF document), its files and the notes on them."""
    from brdffit import jsonout

    doc = document(params, name)
    notes = [note for *_, note in _extensions(params)]
    return doc, {f"{name}.gltf": jsonout.dumps(doc, indent=1)}, notes
