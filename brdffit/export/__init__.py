"""Exports of a fit to renderers: Mitsuba 3, glTF 2.0, MaterialX (docs/exports.md).

``export(result, "mitsuba") -> Export``: the material in the renderer's own format,
the warnings of every clamp and approximation, and the fidelity the conversion kept.
Each target has a module with its mapping and formulas; the conversion of a fit to
the target's own model (exact, or refitted with its loss measured) is
:mod:`brdffit.export.conversion`. CLI (``brdffit export``), service
(``GET /v1/fits/{job_id}/exports/{target}``) and client call this function;
:func:`export_from_store` exports a fit of a batch results file.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field

from brdffit import jsonout
from brdffit.errors import BrdffitError
from brdffit.export import gltf, materialx, mitsuba
from brdffit.fitting.result import FitResult

#: The version of the export schema that :meth:`Export.to_dict` writes.
SCHEMA = "brdffit.export/1"

#: target -> its module (TARGET_MODELS, MEDIA_TYPE and the writer).
TARGETS = {"mitsuba": mitsuba, "gltf": gltf, "materialx": materialx}


class ExportError(BrdffitError, ValueError):
    """An export that cannot be made: unknown target, or a fit with nothing to export."""


@dataclass
class Export:
    """One fit as one renderer's material.

    ``material``: the renderer's document: for ``mitsuba`` the ``mi.load_dict``
    dictionary, for ``gltf`` the glTF JSON document, for ``materialx`` the XML text;
    ``files``: the same material as the files a user saves (name -> text), e.g. the
    Mitsuba scene XML. ``fidelity``: ``exact``, the ``target_model`` the renderer
    shades with, ``log_rmse_to_fit`` (what the conversion lost; 0 when exact), the
    fit's own ``fit_log_rmse`` to its table, and the material's largest directional
    albedo ``albedo_max`` (RGB) at ``albedo_max_theta_deg`` (``brdffit.export.energy``).
    """

    target: str
    source_model: str
    media_type: str
    material: dict | str
    files: dict[str, str]
    fidelity: dict
    target_params: dict
    warnings: list[str] = field(default_factory=list)
    table: str | None = None

    def to_dict(self) -> dict:
        return {"schema": SCHEMA, **asdict(self)}

    def to_json(self, **kw) -> str:
        return jsonout.dumps(self.to_dict(), **kw)

    @classmethod
    def from_dict(cls, d: dict) -> Export:
        """An export from :meth:`to_dict`'s output; refuses another schema version."""
        d = dict(d)
        schema = d.pop("schema", SCHEMA)
        if schema != SCHEMA:
            raise ValueError(f"export schema {schema!r}; this brdffit reads {SCHEMA!r}")
        return cls(**d)


def export_from_store(store: str, table: str, target: str, model: str | None = None) -> Export:
    """The ``model`` fit (None: the best) of ``table`` in the batch results file
    ``store`` (``brdffit batch``) as a material of ``target``: :func:`export` of
    ``brdffit.batch.store.read_fit``'s result. ``table`` is the table's name in the
    file, its path or its file name; an unknown one is an error that lists what the
    file holds."""
    from brdffit.batch.store import read_fit

    if target not in TARGETS:  # before the file is opened
        raise ExportError(f"unknown export target {target!r}; choose one of {', '.join(TARGETS)}")
    return export(FitResult.from_dict(read_fit(store, table, model)), target)


def _material_name(result: FitResult) -> str:
    stem = (result.table or "material").replace("\\", "/").rsplit("/", 1)[-1]
    return f"{stem.removesuffix('.binary')}_{result.model}"


def export(result: FitResult, target: str) -> Export:
    """``result`` as a material of ``target`` (one of ``TARGETS``)."""
    from brdffit.export.conversion import convert
    from brdffit.export.energy import energy_report

    if target not in TARGETS:
        raise ExportError(f"unknown export target {target!r}; choose one of {', '.join(TARGETS)}")
    if not result.params:
        raise ExportError(f"the {result.model} fit has no parameters to export ({result.result})")
    module = TARGETS[target]
    conv = convert(result, module.TARGET_MODELS)
    energy, energy_warnings = energy_report(conv.target_model, conv.params)
    warnings = conv.warnings + energy_warnings
    name = _material_name(result)
    if target == "mitsuba":
        material = mitsuba.load_dict(conv.params)
        files = {f"{name}.xml": mitsuba.scene_xml(material, name)}
    elif target == "gltf":
        material = gltf.document(conv.params, name)
        files = {f"{name}.gltf": jsonout.dumps(material, indent=1)}
        if "ior" in conv.params:
            warnings.append(gltf.IOR_NOTE)
    else:
        material = materialx.document(conv.params, name)
        files = {f"{name}.mtlx": material}
        warnings.append(materialx.SHADING_NOTE)
    return Export(target, result.model, module.MEDIA_TYPE, material, files,
                  {**conv.fidelity(result), **energy}, conv.params, warnings, result.table)
