"""Mitsuba 3 export: a ``mi.load_dict`` dictionary and the same material as scene XML.

Target models (docs/models.md), Mitsuba's own plugins:

- ``rough_conductor``, the default: a metal, or a blend of one with a diffuse base::

    {"type": "blendbsdf", "weight": weight,
     "bsdf_0": {"type": "roughconductor", "distribution": "ggx", "alpha": alpha,
                "eta": <eta>, "k": <k>},
     "bsdf_1": {"type": "diffuse", "reflectance": <kd RGB>}}

  ``blendbsdf`` evaluates ``(1 - weight) bsdf_0 + weight bsdf_1``; with ``weight = 0``
  the export is the ``roughconductor`` alone.
- ``rough_plastic``: a dielectric, for plastics, paints and fabrics (a refit that comes
  out a conductor blend is weighed against it and ``principled``:
  ``conversion.dielectric_or_mixture``)::

    {"type": "roughplastic", "distribution": "ggx", "alpha": alpha, "int_ior": eta,
     "ext_ior": 1.0, "diffuse_reflectance": <kd RGB>, "specular_reflectance": <ks RGB>}

- ``lambert``: Mitsuba's ``diffuse`` plugin, ``kd / pi`` exactly: a ``lambert`` fit is
  copied to it (it was refitted as a conductor blend: a diffuse base under a black
  conductor whose eta, k and alpha shape nothing, a file that reads as a metal)::

    {"type": "diffuse", "reflectance": <kd RGB>}

- ``principled``: a dielectric with Burley's diffuse and a sheen, for fabrics::

    {"type": "principled", "base_color": <RGB>, "roughness": r, "specular": s,
     "sheen": sheen, "sheen_tint": tint}

``kd`` and ``ks`` are reflectances in [0, 1], the models' bounds, so every variant
takes them as they are (a spectral one upsamples them as reflectances, which keeps
their sRGB colour).

``eta`` and ``k`` are not reflectances, and their meaning depends on the variant:

- **RGB variants** (``scalar_rgb``, ``llvm_ad_rgb``, ...; ``load_dict(params)``): the
  triples, as ``srgb`` textures with ``unbounded = true``, which these variants take
  as given (in the XML a plain ``<rgb>``, which the XML reader leaves unbounded where
  the plugin does not expect a reflectance).
- **Spectral variants** (``scalar_spectral``, ``llvm_ad_spectral``, their
  ``_polarized`` kin; ``load_dict(params, spectral=True)``): such an ``srgb`` texture
  is upsampled as a reflectance there and clipped to [0, 1] (``eta = [5, 10, 10]``
  becomes 1 at every wavelength: no reflection at all), so the spectral form writes
  ``regular`` spectra over [360, 830] nm, fitted so that Mitsuba's projection of the
  spectral Fresnel onto sRGB is the RGB variants' Fresnel colour
  (:mod:`brdffit.export.spectral_ior`); a triple whose channels are equal is the
  number itself. An RGB variant loads this form but cannot render it (Mitsuba 3.6.4:
  ``RegularSpectrum::eval(): not implemented``), so each kind of variant has its own
  dictionary: :func:`load_dict_for_variant` picks by the variant's name. Monochrome
  variants are refused (they render one luminance Fresnel, not a colour).
"""

from __future__ import annotations

from xml.sax.saxutils import quoteattr

import numpy as np

from brdffit.errors import BrdffitError
from brdffit.export import spectral_ior

#: the models a fit is copied to (any other fit is refitted as the first: principled's
#: coat is a dielectric's, not layered over rough_conductor, so a coat is named lost)
TARGET_MODELS = ("rough_conductor", "rough_plastic", "principled", "principled_clearcoat",
                 "lambert")
#: target model -> the model that evaluates the file as Mitsuba does: its BSDF.eval
#: agrees with rough_conductor to 2.1e-5 relative, with rough_plastic to 4e-6 and with
#: principled and lambert (its ``diffuse``) to float32 rounding (docs/exports.md,
#: tests/test_export_tools.py)
SHADED_AS = {m: m for m in TARGET_MODELS}
MEDIA_TYPE = "application/json"

#: Largest relative error (floored at F = 0.01, over cos_d in [0, 1] and the channels)
#: of the spectral form's projected Fresnel against the RGB one that an export accepts.
SPECTRAL_TOLERANCE = 0.02


def out_of_range(model: str, params: dict) -> str | None:
    """Why Mitsuba cannot load ``model``'s ``params`` as they are (None: it can): a
    ``lambert`` fit brighter than 1 (a table in other units, a fluorescent sample), which
    Mitsuba's ``diffuse`` refuses ("Invalid RGB reflectance value, must be in the range
    [0, 1]") where the model has no bound; the file was written, and did not load."""
    if model == "lambert" and float(np.max(np.asarray(params["kd"], float))) > 1.0:
        return (f"kd {np.round(np.asarray(params['kd'], float), 4).tolist()} is above 1, "
                "which Mitsuba's diffuse reflectance cannot hold (its range is [0, 1])")
    return None


class SpectralExportError(BrdffitError, ValueError):
    """A material that a Mitsuba variant cannot render as the RGB variants do."""


def _rgb(value, unbounded: bool) -> dict:
    colour = [float(x) for x in value]
    if unbounded:
        return {"type": "srgb", "color": colour, "unbounded": True}
    return {"type": "rgb", "value": colour}


def _spectrum(nodes: np.ndarray) -> dict:
    return {"type": "regular", "wavelength_min": float(spectral_ior.NODES[0]),
            "wavelength_max": float(spectral_ior.NODES[-1]),
            "values": ", ".join(f"{float(v):.9g}" for v in nodes)}


def _spectral_ior(eta, k) -> tuple[float | dict, float | dict]:
    """eta, k for a spectral variant: numbers where every channel is equal, else the
    fitted ``regular`` spectra; refused where the fit misses the RGB Fresnel."""
    eta = np.asarray(eta, float)
    k = np.asarray(k, float)
    if np.all(eta == eta[0]) and np.all(k == k[0]):
        return float(eta[0]), float(k[0])
    fitted = spectral_ior.fit_spectra(eta, k)
    if not fitted.error <= SPECTRAL_TOLERANCE:
        raise SpectralExportError(
            f"eta={eta.tolist()}, k={k.tolist()}: in Mitsuba's spectral "
            f"variants (scalar_spectral, llvm_ad_spectral, ...) no eta, k spectra found give "
            f"its RGB Fresnel colour: the closest is {100 * fitted.error:.1f}% off "
            f"(tolerance {100 * SPECTRAL_TOLERANCE:g}%); render it in an RGB variant "
            f"(scalar_rgb, llvm_ad_rgb) with load_dict(params)")
    return _spectrum(fitted.eta), _spectrum(fitted.k)


def load_dict(params: dict, spectral: bool = False) -> dict:
    """The Mitsuba 3 BSDF dictionary of ``rough_conductor``, ``rough_plastic``,
    ``principled`` or ``lambert`` parameters (told apart by ``k``, ``sheen`` and ``kd``
    alone), for Mitsuba's RGB variants, or with ``spectral=True`` for its spectral ones
    (module docstring). Raises :class:`SpectralExportError` where a spectral form would
    not be the same material."""
    if "sheen" in params:
        return _principled(params, spectral)
    if set(params) == {"kd"}:
        return {"type": "diffuse", "reflectance": _reflectance(params["kd"], "kd", spectral)}
    if "k" not in params:
        return _plastic(params, spectral)
    if spectral:
        eta, k = _spectral_ior(params["eta"], params["k"])
    else:
        eta, k = _rgb(params["eta"], True), _rgb(params["k"], True)
    conductor = {
        "type": "roughconductor",
        "distribution": "ggx",
        "alpha": float(params["alpha"]),
        "eta": eta,
        "k": k,
    }
    weight = float(params["weight"])
    if weight == 0.0:
        return conductor
    return {
        "type": "blendbsdf",
        "weight": weight,
        "bsdf_0": conductor,
        "bsdf_1": {"type": "diffuse", "reflectance": _reflectance(params["kd"], "kd", spectral)},
    }


def _plastic(params: dict, spectral: bool) -> dict:
    """``roughplastic`` of ``rough_plastic`` parameters: ``ext_ior`` 1 (Mitsuba's
    default is air's 1.000277), so that ``int_ior`` is the model's relative ``eta``."""
    return {
        "type": "roughplastic",
        "distribution": "ggx",
        "alpha": float(params["alpha"]),
        "int_ior": float(params["eta"]),
        "ext_ior": 1.0,
        "diffuse_reflectance": _reflectance(params["kd"], "kd", spectral),
        "specular_reflectance": _reflectance(params["ks"], "ks", spectral),
    }


def _principled(params: dict, spectral: bool) -> dict:
    """``principled`` of ``principled`` (or ``principled_clearcoat``) parameters:
    metallic, spec_trans, spec_tint, flatness, anisotropic and (but for
    ``principled_clearcoat``) clearcoat left at their default 0."""
    out = {
        "type": "principled",
        "base_color": _reflectance(params["base_color"], "base_color", spectral),
        "roughness": float(params["roughness"]),
        "specular": float(params["specular"]),
        "sheen": float(params["sheen"]),
        "sheen_tint": float(params["sheen_tint"]),
    }
    if "clearcoat" in params:
        out.update(clearcoat=float(params["clearcoat"]),
                   clearcoat_gloss=float(params["clearcoat_gloss"]))
    return out


def _reflectance(value, name: str, spectral: bool) -> dict | float:
    """A reflectance in [0, 1] (``kd``, ``ks``): an ``rgb`` for RGB variants; for a
    spectral variant a number where the channels are equal (0: no reflection, in every
    variant), else a ``regular`` reflectance spectrum fitted to its colour
    (``spectral_ior.fit_reflectance``). Mitsuba's own upsampling of an ``rgb``
    reflectance is right to the eye but not in relative terms where the colour is dark
    and saturated: blue-metallic-paint's conductor fit, kd = [1.2e-8, 7.8e-9, 2e-11] at
    blend weight 0.79, rendered 6% too red in scalar_spectral, its ggx export
    (kd = [0, 0, 0.002]) 8% too blue."""
    if not spectral:
        return _rgb(value, False)
    value = np.asarray(value, float)
    if np.all(value == value[0]):
        return float(value[0])
    values = spectral_ior.fit_reflectance(value)
    if not spectral_ior.reflectance_error(values, value) <= SPECTRAL_TOLERANCE:
        raise SpectralExportError(
            f"{name}={value.tolist()}: no reflectance spectrum found gives this colour in "
            "Mitsuba's spectral variants (scalar_spectral, ...); render it in an RGB "
            "variant (scalar_rgb, llvm_ad_rgb) with load_dict(params)")
    return _spectrum(values)


def load_dict_for_variant(params: dict, variant: str | None = None) -> dict:
    """:func:`load_dict`'s form for the Mitsuba ``variant`` (default: the one set,
    ``mitsuba.variant()``): the spectral form in a ``*_spectral*`` variant, the RGB form
    in an ``*_rgb`` one; a monochrome variant is refused."""
    if variant is None:
        import mitsuba as mi

        variant = mi.variant()
        if variant is None:
            raise SpectralExportError("no Mitsuba variant is set: call mitsuba.set_variant "
                                      "first, or pass variant=")
    if "_mono" in variant:
        raise SpectralExportError(
            f"Mitsuba variant {variant!r} renders one luminance channel; brdffit's "
            f"Mitsuba export is an RGB material (use an _rgb or _spectral variant)")
    if "_spectral" in variant:
        return load_dict(params, spectral=True)
    if variant.endswith("_rgb"):
        return load_dict(params)
    raise SpectralExportError(f"unknown Mitsuba variant {variant!r}")


def _xml(node: dict, name: str | None, indent: str) -> list[str]:
    """One dictionary node as Mitsuba scene XML (the subset ``load_dict`` above writes).

    A nested BSDF is a child ``<bsdf>`` without a name (blendbsdf takes them in order).
    """
    kind = node["type"]
    if kind == "rgb":
        return [f'{indent}<rgb name={quoteattr(name)} value="{_floats(node["value"])}"/>']
    if kind == "srgb":  # the XML reader keeps an <rgb> of a non-reflectance unbounded
        return [f'{indent}<rgb name={quoteattr(name)} value="{_floats(node["color"])}"/>']
    if kind == "regular":
        return [f'{indent}<spectrum name={quoteattr(name)} type="regular">',
                f'{indent}    <float name="wavelength_min" value="{node["wavelength_min"]!r}"/>',
                f'{indent}    <float name="wavelength_max" value="{node["wavelength_max"]!r}"/>',
                f'{indent}    <string name="values" value={quoteattr(node["values"])}/>',
                f"{indent}</spectrum>"]
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
    reference from a shape with ``<ref id=.../>``. The file is for the variants its
    dictionary is for: ``scene_xml(load_dict(params))`` for RGB variants,
    ``scene_xml(load_dict(params, spectral=True))`` for spectral ones."""
    # Mitsuba reserves ids that start with "_" ("invalid id: leading underscores are
    # reserved"): a table named _lab.binary gave files that did not load
    material_id = material_id.lstrip("_ ") or "brdffit_material"
    lines = _xml(material, None, "    ")
    lines[0] = lines[0].replace(f'<bsdf type="{material["type"]}"',
                                f'<bsdf type="{material["type"]}" id={quoteattr(material_id)}', 1)
    return '<scene version="3.0.0">\n' + "\n".join(lines) + "\n</scene>\n"


#: Which of Mitsuba's variants each of an export's dictionaries is for
#: (``Export.variants``; ``material`` is the RGB one).
VARIANTS = {"rgb": "scalar_rgb, llvm_ad_rgb, cuda_ad_rgb (and their _polarized kin; "
                   "a _mono variant is refused: variant())",
            "spectral": "scalar_spectral, llvm_ad_spectral, cuda_ad_spectral (and their "
                        "_polarized kin)"}
#: What the two files are for, where both are written (``NAME``: the material's name).
VARIANTS_NOTE = ("variants: NAME.xml (and the material, a load_dict dictionary) is for "
                 "Mitsuba's RGB variants; in a spectral variant load NAME_spectral.xml (or "
                 "variants['spectral']): the RGB one there is 10-25% off in colour")


def write(params: dict, name: str, target_model: str,
          made: tuple[dict, dict | str] | None = None) -> tuple[dict, dict[str, str], list[str]]:
    """The material (the load_dict dictionary, for RGB variants), its files and the
    notes on them: ``NAME.xml`` for Mitsuba's RGB variants and ``NAME_spectral.xml``
    for its spectral ones (eta, k as fitted spectra), or a note where no spectrum
    reproduces the RGB colour within SPECTRAL_TOLERANCE. ``made``: :func:`variants`
    of ``params`` where the caller has them (the spectra's fit is not repeated)."""
    material, spectral = variants(params) if made is None else made
    files = {f"{name}.xml": scene_xml(material, name)}
    notes = []
    if isinstance(spectral, dict):
        files[f"{name}_spectral.xml"] = scene_xml(spectral, name)
        notes.append(VARIANTS_NOTE.replace("NAME", name))
    else:  # no spectral file: the note on the two would point at none
        notes.append(f"spectral: {spectral}")
    return material, files, notes


def variants(params: dict) -> tuple[dict, dict | str]:
    """The RGB variants' dictionary and the spectral variants' one, or in its place
    why there is none (no spectrum reproduces the RGB colour within
    SPECTRAL_TOLERANCE)."""
    try:
        return load_dict(params), load_dict(params, spectral=True)
    except SpectralExportError as e:
        return load_dict(params), str(e)
