"""Mitsuba 3 export: a ``mi.load_dict`` dictionary and the same material as scene XML.

Target model ``rough_conductor`` (docs/models.md), which is Mitsuba's own plugins:

    {"type": "blendbsdf", "weight": weight,
     "bsdf_0": {"type": "roughconductor", "distribution": "ggx", "alpha": alpha,
                "eta": <eta RGB>, "k": <k RGB>},
     "bsdf_1": {"type": "diffuse", "reflectance": <kd RGB>}}

``blendbsdf`` evaluates ``(1 - weight) bsdf_0 + weight bsdf_1``; with ``weight = 0``
the export is the ``roughconductor`` alone. ``eta`` and ``k`` are not reflectances
(they exceed 1), so they are written as ``srgb`` textures with ``unbounded = true``,
which Mitsuba's RGB variants take as given (in the XML a plain ``<rgb>``, which the
XML reader leaves unbounded where the plugin does not expect a reflectance); ``kd`` is a
reflectance in [0, 1], the model's bound, so Mitsuba accepts it unchanged.
"""

from __future__ import annotations

from xml.sax.saxutils import quoteattr

TARGET_MODELS = ("rough_conductor",)
#: target model -> the model that evaluates the file as Mitsuba does: its BSDF.eval
#: agrees with rough_conductor to 2.1e-5 relative (docs/exports.md)
SHADED_AS = {"rough_conductor": "rough_conductor"}
MEDIA_TYPE = "application/json"


def _rgb(value, unbounded: bool) -> dict:
    colour = [float(x) for x in value]
    if unbounded:
        return {"type": "srgb", "color": colour, "unbounded": True}
    return {"type": "rgb", "value": colour}


def load_dict(params: dict) -> dict:
    """The Mitsuba 3 BSDF dictionary of ``rough_conductor`` parameters."""
    conductor = {
        "type": "roughconductor",
        "distribution": "ggx",
        "alpha": float(params["alpha"]),
        "eta": _rgb(params["eta"], True),
        "k": _rgb(params["k"], True),
    }
    weight = float(params["weight"])
    if weight == 0.0:
        return conductor
    return {
        "type": "blendbsdf",
        "weight": weight,
        "bsdf_0": conductor,
        "bsdf_1": {"type": "diffuse", "reflectance": _rgb(params["kd"], False)},
    }


def _xml(node: dict, name: str | None, indent: str) -> list[str]:
    """One dictionary node as Mitsuba scene XML (the subset ``load_dict`` above writes).

    A nested BSDF is a child ``<bsdf>`` without a name (blendbsdf takes them in order).
    """
    kind = node["type"]
    if kind == "rgb":
        return [f'{indent}<rgb name={quoteattr(name)} value="{_floats(node["value"])}"/>']
    if kind == "srgb":  # the XML reader keeps an <rgb> of a non-reflectance unbounded
        return [f'{indent}<rgb name={quoteattr(name)} value="{_floats(node["color"])}"/>']
    lines = [f'{indent}<bsdf type="{kind}">']
    for key, value in node.items():
        if key == "type":
            continue
        if isinstance(value, dict):
            lines += _xml(value, key, indent + "    ")
        elif isinstance(value, str):
            lines.append(f'{indent}    <string name="{key}" value={quoteattr(value)}/>')
        else:
            lines.append(f'{indent}    <float name="{key}" value="{float(value)!r}"/>')
    lines.append(f"{indent}</bsdf>")
    return lines


def _floats(values) -> str:
    return ", ".join(repr(float(x)) for x in values)


def scene_xml(material: dict, material_id: str = "brdffit_material") -> str:
    """A Mitsuba 3 scene file declaring the material (``<bsdf id=...>``), ready to
    reference from a shape with ``<ref id=.../>``."""
    lines = _xml(material, None, "    ")
    lines[0] = lines[0].replace(f'<bsdf type="{material["type"]}"',
                                f'<bsdf type="{material["type"]}" id="{material_id}"', 1)
    return '<scene version="3.0.0">\n' + "\n".join(lines) + "\n</scene>\n"


def write(params: dict, name: str, target_model: str) -> tuple[dict, dict[str, str], list[str]]:
    """The material (the load_dict dictionary), its files and the notes on them."""
    material = load_dict(params)
    return material, {f"{name}.xml": scene_xml(material, name)}, []
