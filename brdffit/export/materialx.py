"""MaterialX export: a ``standard_surface`` or ``gltf_pbr`` shader and its material (1.39).

Target models (docs/models.md), the first the default:

- ``standard_surface``: MaterialX's ``standard_surface`` node
  (``ND_standard_surface_surfaceshader``) as MaterialX's own GLSL shades it. The model's
  parameters are the node's inputs under the same names, so the mapping is a copy:

      base_color, metalness, specular_color, specular_roughness, specular_IOR

  and ``base = 1``, ``specular = 1``, ``diffuse_roughness = 0`` (MaterialX's defaults,
  which the model holds:
  ``brdffit.models.standard_surface.FIXED_INPUTS``); every other input
  at its default (no coat, sheen, subsurface, transmission, thin film or emission,
  ``specular_anisotropy`` 0): the model's own assumptions. The export is exact: the
  generated GLSL run on OpenGL agrees with the model to 1e-5 relative (7e-5 at
  89.9 degrees, the shader's float32)
  (``brdffit.export.validate.materialx_eval``, ``tests/test_materialx_shading.py``).
- ``standard_surface_coat``, ``standard_surface_sheen``: the same node with its coat
  (``coat``, ``coat_roughness``; ``coat_IOR`` 1.5 written) or its sheen (``sheen``,
  ``sheen_color``, ``sheen_roughness``), as MaterialX's GLSL shades them (1e-6); a fit
  with a coat or a sheen is refitted as these rather than the plain node.
- ``gltf_pbr``, ``gltf_pbr_ior``: MaterialX's ``gltf_pbr`` node
  (``ND_gltf_pbr_surfaceshader``), inputs glTF's parameters under the same names:
  ``base_color``, ``metallic``, ``roughness`` (and ``ior``); the other inputs at their
  defaults. Not exact: MaterialX implements that node as a graph of its BSDF nodes,
  which layers the dielectric lobe over the diffuse one by the lobe's directional
  albedo rather than by glTF Appendix B's ``(1 - F)``; the parameters are glTF's
  exactly, the shading agrees with the spec's formula only as closely as that graph
  does (:data:`SHADING_NOTE`, for the export's warnings).
"""

from __future__ import annotations

from xml.sax.saxutils import quoteattr

#: the models a fit is copied to by default (any other fit is refitted as the first, or
#: as the one layered over it that keeps the fit's coat or sheen);
#: ``export(..., target_model=)`` chooses among every key of SHADED_AS
TARGET_MODELS = ("standard_surface", "standard_surface_dielectric", "standard_surface_coat",
                 "standard_surface_sheen", "generalized_schlick")
#: target model -> the model that evaluates the file as MaterialX shades it: its
#: generated GLSL agrees with standard_surface to 1e-5 (validate.materialx_eval); its
#: shading of the gltf_pbr node is not modelled (None)
SHADED_AS = {"standard_surface": "standard_surface",
             "standard_surface_dielectric": "standard_surface_dielectric",
             "standard_surface_coat": "standard_surface_coat",
             "standard_surface_sheen": "standard_surface_sheen",
             "generalized_schlick": "generalized_schlick",
             "gltf_pbr": None, "gltf_pbr_ior": None}
UNMODELLED_NOTE = ("fidelity: MaterialX's own shading of its gltf_pbr node is not modelled, "
                   "so log_rmse_to_table is not measured; the default standard_surface is")
MEDIA_TYPE = "application/mtlx+xml"
SHADING_NOTE = ("MaterialX's gltf_pbr node layers its specular lobe over the diffuse by "
                "directional albedo, not glTF Appendix B's (1 - F): the parameters are exact, "
                "the shading there is MaterialX's approximation of the spec")

#: standard_surface model parameter -> (MaterialX input type); the names are the inputs'.
STANDARD_SURFACE_INPUTS = {
    "base_color": "color3", "metalness": "float", "specular_color": "color3",
    "specular_roughness": "float", "specular_IOR": "float",
}
#: the inputs the model holds fixed (models/standard_surface.py FIXED_INPUTS), written too
STANDARD_SURFACE_FIXED = {"base": 1.0, "specular": 1.0, "diffuse_roughness": 0.0}
#: standard_surface_coat's coat (models/standard_surface_coat.py): its two parameters,
#: and the index it holds (its COAT_IOR; not imported: writing a document loads no JAX)
COAT_INPUTS = {"coat": "float", "coat_roughness": "float"}
COAT_FIXED = {"coat_IOR": 1.5}
#: standard_surface_sheen's sheen (models/standard_surface_sheen.py)
SHEEN_INPUTS = {"sheen": "float", "sheen_color": "color3", "sheen_roughness": "float"}
#: the layered models: node standard_surface, these inputs beside its own
LAYER_INPUTS = {"standard_surface_coat": (COAT_INPUTS, COAT_FIXED),
                "standard_surface_sheen": (SHEEN_INPUTS, {})}
GLTF_PBR_INPUTS = {"base_color": "color3", "metallic": "float", "roughness": "float",
                   "ior": "float"}
#: generalized_schlick (models/generalized_schlick.py): the lobe's inputs under their
#: names, its roughness written on both axes, over an oren_nayar_diffuse_bsdf of colour kd
GENERALIZED_SCHLICK_INPUTS = {"color0": "color3", "color90": "color3", "exponent": "float"}


def shading_notes(model: str) -> list[str]:
    """The export warnings a MaterialX document of ``model`` parameters needs: the
    ``gltf_pbr`` node's :data:`SHADING_NOTE`; none for ``standard_surface``, whose
    model is MaterialX's own shading."""
    return [] if model.startswith("standard_surface") or model == "generalized_schlick" else [
        SHADING_NOTE]


def _identifier(name: str) -> str:
    """A MaterialX element name: ASCII letters, digits and underscores, not starting with
    a digit. Accents are dropped from their letters (``ü``: ``u``), other characters
    made ``_``: MaterialX's validate() refused "SR_金_red_plastic", which str.isalnum let
    through, and the document was written without a word."""
    import unicodedata

    plain = unicodedata.normalize("NFKD", name)
    out = "".join(c if (c.isascii() and c.isalnum()) or c == "_" else "" if
                  unicodedata.combining(c) else "_" for c in plain) or "brdffit"
    return out if not out[0].isdigit() else f"m_{out}"


def _input(name: str, kind: str, value) -> str:
    if kind == "color3":
        text = ", ".join(repr(float(x)) for x in value)
    else:
        text = repr(float(value))
    return f'    <input name="{name}" type="{kind}" value="{text}"/>'


def document(params: dict, name: str, model: str | None = None) -> str:
    """The MaterialX document (XML text) of ``model`` parameters (one of
    :data:`SHADED_AS`): a ``standard_surface`` node for ``standard_surface`` (with its
    coat or sheen for ``standard_surface_coat``, ``_sheen``), a ``surface`` of a
    ``generalized_schlick_bsdf`` layered over an ``oren_nayar_diffuse_bsdf`` for
    ``generalized_schlick``, a ``gltf_pbr`` node for
    ``gltf_pbr`` and ``gltf_pbr_ior``, and its ``surfacematerial``. ``model=None``: the model whose
    parameters ``params`` holds (``coat``: standard_surface_coat; ``sheen``:
    standard_surface_sheen; ``metalness``:
    standard_surface; ``specular_IOR`` alone: standard_surface_dielectric, written as
    the node at metalness 0; ``ior``: gltf_pbr_ior; else gltf_pbr)."""
    if model is None:
        model = ("generalized_schlick" if "color90" in params
                 else "standard_surface_coat" if "coat" in params
                 else "standard_surface_sheen" if "sheen" in params
                 else "standard_surface" if "metalness" in params
                 else "standard_surface_dielectric" if "specular_IOR" in params
                 else "gltf_pbr_ior" if "ior" in params else "gltf_pbr")
    if model not in SHADED_AS:
        raise ValueError(f"MaterialX writes {', '.join(SHADED_AS)} parameters, not {model!r}")
    if model == "standard_surface_dielectric":  # its node at metalness 0
        model, params = "standard_surface", {**params, "metalness": 0.0}
    ident = _identifier(name)
    shader = quoteattr("SR_" + ident)
    nodes: list[str] = []
    if model == "generalized_schlick":
        nodes, node, inputs = _generalized_schlick(params, ident), "surface", [
            f'    <input name="bsdf" type="BSDF" nodename={quoteattr("BSDF_" + ident)}/>']
    elif model == "standard_surface" or model in LAYER_INPUTS:
        node = "standard_surface"
        inputs = [_input(k, "float", v) for k, v in STANDARD_SURFACE_FIXED.items()]
        inputs += [_input(k, kind, params[k]) for k, kind in STANDARD_SURFACE_INPUTS.items()]
        layer, fixed = LAYER_INPUTS.get(model, ({}, {}))
        inputs += [_input(k, kind, params[k]) for k, kind in layer.items()]
        inputs += [_input(k, "float", v) for k, v in fixed.items()]
    else:
        node = "gltf_pbr"
        inputs = [_input(k, kind, params[k]) for k, kind in GLTF_PBR_INPUTS.items()
                  if k in params]
    return "\n".join([
        '<?xml version="1.0"?>',
        '<materialx version="1.39">',
        *nodes,
        f'  <{node} name={shader} type="surfaceshader">',
        *inputs,
        f"  </{node}>",
        f'  <surfacematerial name={quoteattr("M_" + ident)} type="material">',
        f'    <input name="surfaceshader" type="surfaceshader" nodename={shader}/>',
        "  </surfacematerial>",
        # a look that puts the material on every geometry: a viewer that applies looks
        # (MaterialXView, Houdini, Maya's LookdevX) shows it on whatever it loads
        f'  <look name={quoteattr("L_" + ident)}>',
        f'    <materialassign name={quoteattr("MA_" + ident)} '
        f'material={quoteattr("M_" + ident)} geom="/*"/>',
        "  </look>",
        "</materialx>",
        "",
    ])


def _generalized_schlick(params: dict, ident: str) -> list[str]:
    """The BSDF nodes of a generalized_schlick fit: its lobe layered over its diffuse
    (``layer``: the diffuse dimmed by the lobe's throughput), as the model shades it."""
    lobe, diffuse, layered = (quoteattr(f"{p}_{ident}") for p in ("LOBE", "DIFFUSE", "BSDF"))
    alpha = float(params["alpha"])
    return [
        f'  <oren_nayar_diffuse_bsdf name={diffuse} type="BSDF">',
        _input("color", "color3", params["kd"]),
        _input("roughness", "float", 0.0),
        "  </oren_nayar_diffuse_bsdf>",
        f'  <generalized_schlick_bsdf name={lobe} type="BSDF">',
        *(_input(k, kind, params[k]) for k, kind in GENERALIZED_SCHLICK_INPUTS.items()),
        f'    <input name="roughness" type="vector2" value="{alpha!r}, {alpha!r}"/>',
        "  </generalized_schlick_bsdf>",
        f'  <layer name={layered} type="BSDF">',
        f'    <input name="top" type="BSDF" nodename={lobe}/>',
        f'    <input name="base" type="BSDF" nodename={diffuse}/>',
        "  </layer>",
    ]


def write(params: dict, name: str, target_model: str) -> tuple[str, dict[str, str], list[str]]:
    """The material (the XML text), its files and the notes on them."""
    text = document(params, name, target_model)
    return text, {f"{name}.mtlx": text}, shading_notes(target_model)
