"""Exports of a fit to renderers: Mitsuba 3, glTF 2.0, MaterialX (docs/exports.md).

``export(result, "mitsuba") -> Export``: the material in the renderer's own format,
the warnings of every clamp and approximation, and the fidelity the conversion kept.
Each target (:data:`TARGETS`, an :class:`ExportTarget` each) has a module with its
mapping and formulas; the conversion of a fit to the target's own model (exact, or
refitted with its loss measured) is :mod:`brdffit.export.conversion`. CLI (``brdffit
export``), service (``GET /v1/fits/{job_id}/exports/{target}``) and client call this
function; ``brdffit.batch.exports.export_from_store`` exports a fit of a batch results
file.
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from dataclasses import asdict, dataclass, field
from types import MappingProxyType, ModuleType

import numpy as np

from brdffit import jsonout
from brdffit.errors import BrdffitError, ExportError  # noqa: F401 - ExportError re-exported
from brdffit.export import gltf, materialx, mitsuba
from brdffit.fitting.result import FitResult
from brdffit.io.merl import MerlTable

#: The version of the export schema that :meth:`Export.to_dict` writes. 2:
#: ``fidelity.sphere_colour`` (brightness in stops, CIEDE2000) replaces the per-channel
#: ``sphere_colour_error``.
SCHEMA = "brdffit.export/2"


# one object per target: compared and hashed by identity (its viewers are a dict)
@dataclass(frozen=True, eq=False)
class ExportTarget:
    """One renderer a fit can be exported to: its module (``TARGET_MODELS``,
    ``SHADED_AS``, ``MEDIA_TYPE``, ``write``; ``UNMODELLED_NOTE`` where a model it
    carries is shaded as nothing brdffit models) and what its exports have besides
    the material."""

    name: str
    label: str  # as its users write it, in messages
    module: ModuleType
    #: viewer -> the target model that the export for it carries (a layered fit: the
    #: viewer's model that keeps its layers, ``_viewer_model``)
    #: (``export(..., viewer=)``; the module's ``VIEWER_IGNORES``: what each viewer
    #: does not read), each judged in ``fidelity.viewers``; empty: the renderer's own
    #: shading only
    viewers: Mapping[str, str] = field(default_factory=dict)
    #: its document can be saved as one binary ``.glb`` (the module's ``to_glb``)
    glb: bool = False
    #: each variant family's dictionary (``Export.variants``; the module's ``variants``,
    #: ``VARIANTS``, and a ``write`` that takes them and notes what each file is for)
    variants: bool = False

    @property
    def media_type(self) -> str:
        return self.module.MEDIA_TYPE

    @property
    def target_models(self) -> tuple[str, ...]:
        """The models the target carries, its default first."""
        return self.module.TARGET_MODELS

    @property
    def shaded_as(self) -> dict[str, str | None]:
        """Target model -> the brdffit model the renderer shades it as (None: not modelled)."""
        return self.module.SHADED_AS

    #: the target modules' own spelling, which the shells read from :data:`TARGETS`
    SHADED_AS = shaded_as


#: Every export target by name (``brdffit export --to``, the service's
#: ``/exports/{target}``).
TARGETS: Mapping[str, ExportTarget] = MappingProxyType({t.name: t for t in (
    ExportTarget("mitsuba", "Mitsuba", mitsuba, variants=True),
    ExportTarget("gltf", "glTF", gltf, viewers=gltf.VIEWERS, glb=True),
    ExportTarget("materialx", "MaterialX", materialx),
)})


def get_target(name: str) -> ExportTarget:
    """The export target ``name``; :class:`ExportError` naming the choices for any other."""
    try:
        return TARGETS[name]
    except KeyError:
        raise ExportError(f"unknown export target {name!r}; choose one of {', '.join(TARGETS)}") \
            from None


@dataclass
class Export:
    """One fit as one renderer's material.

    ``material``: the renderer's document: for ``mitsuba`` the ``mi.load_dict``
    dictionary, for ``gltf`` the glTF JSON document, for ``materialx`` the XML text;
    ``files``: the same material as the files a user saves (name -> text), e.g. the
    Mitsuba scene XML. ``fidelity``: ``exact``, the ``target_model`` the renderer
    shades with, ``log_rmse_to_fit`` (what the conversion lost; 0 when exact), the
    fit's own ``fit_log_rmse`` to its table, ``sphere_colour``: the exported material's
    lit sphere against the table's (``brightness_stops``, ``displayed_brightness_stops``
    (the one a verdict judges), ``colour_shift`` and ``displayed_colour_shift`` as
    CIEDE2000 (a verdict judges the worse), ``estimate_error``:
    ``brdffit.fitting.sphere.sphere_colour``'s key light), ``render_psnr_db``: its sphere
    renders' PSNR against the table's (a fit's ``quality.render_psnr_db``), and the
    material's largest directional albedo ``albedo_max`` (RGB) at
    ``albedo_max_theta_deg`` (``brdffit.export.energy``). A fit that does not look good
    is exported with a warning that says so and what to try.
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
    #: Mitsuba: each variant family's dictionary, ``{"rgb": ..., "spectral": ...}``
    #: (``material`` is the RGB one; the spectral one None where no spectrum holds the
    #: colour, a warning says why), with ``for`` naming the variants; None elsewhere.
    variants: dict | None = None

    def to_dict(self) -> dict:
        return {"schema": SCHEMA, **asdict(self)}

    def file_bytes(self, glb: bool = False) -> dict[str, bytes]:
        """The files to save, as bytes; ``glb``: a glTF export's document as one binary
        ``.glb`` instead of its ``.gltf`` (``brdffit.export.gltf.to_glb``)."""
        if not glb:
            return {name: text.encode() for name, text in self.files.items()}
        target = get_target(self.target)
        if not target.glb:
            raise ExportError(f"a binary .glb is a glTF file; a {self.target} export has none")
        stem = next(iter(self.files)).removesuffix(".gltf")
        return {f"{stem}.glb": target.module.to_glb(self.material)}

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


def _material_name(result: FitResult, viewer: str = "spec",
                   target_model: str | None = None) -> str:
    """The table's file name without its layout's suffix, and the model: a sample list's
    material was ``lab.csv_ggx`` (files ``lab.csv_ggx.gltf``), a MERL table's ``gold_ggx``;
    an export for a viewer, or as a model asked for, says which (``gold_ggx_threejs``,
    ``gold_ggx_as_principled_clearcoat``): they shared the first's file name, and the
    second export into one folder overwrote the first without a word."""
    from brdffit.io.readers import READERS

    stem = (result.table or "material").replace("\\", "/").rsplit("/", 1)[-1]
    base, suffix = os.path.splitext(stem)
    name = f"{base if base and suffix.lower() in READERS else stem}_{result.model}"
    if viewer != "spec":
        name += f"_{viewer}"
    elif target_model is not None and target_model != result.model:
        name += f"_as_{target_model}"
    return name


def _measured_table(result: FitResult, table) -> tuple[MerlTable | None, bool, list[str]]:
    """The measured table the fidelity is judged against: ``table`` (a MerlTable or a
    path), else the file the fit was read from where it is still there; None, with a
    warning that says so, where neither is at hand. With it, whether it holds the
    table that was fitted, so that the material may be made from it (the viewers'
    refits, the metal-or-dielectric weighing): another table only judges."""
    from brdffit.io import readers

    # a workbook's samples are re-read from the sheet that was fitted (its first sheet
    # of samples may be another)
    sheet = (result.input or {}).get("sheet")
    if table is not None:
        same_file = not isinstance(table, MerlTable) and os.path.basename(
            str(table)) == os.path.basename(result.table or "")
        given = table if isinstance(table, MerlTable) else readers.read_table(
            table, sheet=sheet if same_file else None)[0]
        other = _another_table(result, given)  # by name: all a result keeps of its table
        if other:
            other.append(f"export: the material is made from the {result.model} fit, not "
                         f"from {given.source}, which only judges it")
        return given, not other, other
    source = result.table
    if source and os.path.isfile(source):
        try:  # the fit's own file, in whichever layout it was read
            got = readers.read_measured(source, sheet=sheet)
            own = got if isinstance(got, MerlTable) else got.to_table()[0]
        except BrdffitError as e:
            return None, False, [f"fidelity: log_rmse_to_table not measured: {e}"]
        changed = _changed_since_the_fit(result, own,
                                         None if isinstance(got, MerlTable) else got)
        return own, not changed, changed
    return None, False, [f"fidelity: log_rmse_to_table not measured: the fitted table "
                         f"{source or '(unnamed)'} is not at hand (pass the table: "
                         "export(..., table=...), brdffit export --measured PATH); nor is "
                         "what needs it: a metal mixture is kept unweighed against a "
                         "dielectric, a viewer's model fitted to the fit, not the table"]


def _another_table(result: FitResult, table: MerlTable) -> list[str]:
    """A warning where the table given to measure against is, by its file's name, not
    the one the fit was made on (their names are all a result keeps of them)."""
    fitted, given = (os.path.basename(s or "") for s in (result.table, table.source))
    if not fitted or not given or given.startswith("<") or fitted.startswith("<"):
        return []
    if fitted == given:
        return []
    return [f"fidelity: measured against {table.source}, but the fit was made on "
            f"{result.table}: log_rmse_to_table is to another table than the fit's"]


#: How far (relative) the fit's own log_rmse on the table at hand may differ from the
#: one it reported before the table is taken for another: the full-table error is
#: measured in float32 (~1e-6 apart between runs); a file rewritten since the fit, or
#: another material under its name, is off by far more.
SAME_TABLE_RTOL = 1e-3
#: ... and absolutely: a near-exact fit's log_rmse (~1e-8) is float32 noise, which
#: another machine's run may not repeat.
SAME_TABLE_ATOL = 1e-5


def _changed_since_the_fit(result: FitResult, table: MerlTable,
                           samples=None) -> list[str]:
    """A warning where ``table``, read from the fit's own file, does not give the fit's
    reported log_rmse: the file changed since the fit (a result keeps the table's name
    alone: another material written over it was measured against without a word), and
    every fidelity figure is to what it holds now. A fit at a sample list's own
    directions (``samples``: that file's samples as read now) is checked on them, by
    its log_rmse on every usable sample; a table's fit, on every bin, where it was made
    without a scene (only then did it report that figure)."""
    from brdffit.fitting.problem import table_error
    from brdffit.fitting.samples import sample_error

    on_samples = (result.input or {}).get("fitted_at") == "samples"
    if on_samples != (samples is not None):
        return []
    if on_samples:  # in a scene, its error on every sample is reported apart
        reported = (result.full_table_error or result.error or {}).get("log_rmse")
    elif result.full_table_error is None:
        reported = (result.error or {}).get("log_rmse")
    else:  # a table's fit in a scene: no figure on every bin to compare with
        return []
    if not isinstance(reported, (int, float)) or not np.isfinite(reported) or reported <= 0:
        return []
    now = (sample_error(samples, result.model, result.params) if on_samples
           else table_error(table, result.model, result.params))["log_rmse"]
    if np.isfinite(now) and abs(now - reported) <= max(SAME_TABLE_RTOL * reported,
                                                       SAME_TABLE_ATOL):
        return []
    what = "samples that were" if on_samples else "table that was"
    return [f"fidelity: {table.source} does not hold the {what} fitted: the fit's "
            f"own log_rmse on it is {now:.4g}, {reported:.4g} when it was fitted (the file "
            "changed since, or the fit's parameters were edited?); every fidelity figure is "
            "to the file as it is now"]


def export(result: FitResult, target: str, *, table: MerlTable | str | os.PathLike | None = None,
           target_model: str | None = None, viewer: str = "spec",
           name: str | None = None) -> Export:
    """``result`` as a material of ``target`` (one of ``TARGETS``).

    ``target_model``: which of the target's models the file carries (default: the fit's
    own model where it is one of them, else the target's first, e.g. MaterialX's
    ``standard_surface``, or the model layered over it that keeps the layers the fit
    uses, e.g. ``standard_surface_coat`` for a coat fit). ``table``: the measured
    table, for ``fidelity.log_rmse_to_table`` and the sphere's colour error (default:
    the fit's own table file, where it is still there). ``viewer`` (glTF): ``"spec"``
    (the spec's definition, default), ``"threejs"`` or ``"blender"``: the factors fitted
    for the way three.js or Blender's Cycles shades them (target model ``gltf_threejs``,
    ``gltf_blender``; a layered fit keeps the layers the viewer's models shade: a coat,
    sheen or film fit for three.js is refitted as ``gltf_threejs_clearcoat``, ``_sheen``
    or ``_iridescence``, a coat or sheen fit for Blender as ``gltf_blender_clearcoat`` or
    ``_sheen``). A glTF export's fidelity has ``viewers``: the file under each viewer's
    shading. ``name``: the material's name, and its files' (default: the table's file
    name and the fit's model, ``gold_ggx``).
    """
    from brdffit import models
    from brdffit.export.conversion import convert, dielectric_or_mixture, half_metal_said
    from brdffit.export.energy import energy_report
    from brdffit.fitting.problem import table_error

    spec = get_target(target)
    if not result.params:
        raise ExportError(f"the {result.model} fit has no parameters to export ({result.result})")
    if result.result == "nonfinite":
        # the solve diverged: its last point is no material (it was exported, with every
        # fidelity figure, under one warning)
        raise ExportError(f"the {result.model} fit failed (result nonfinite: its solve "
                          "diverged): nothing to export; refit the table")
    try:
        models.get(result.model).check_params(result.params)
    except models.UnknownModelError:
        pass  # refused below, in the target's words
    except ValueError as e:  # params another tool or a hand edited: said as the fit's
        raise ExportError(f"the {result.model} fit's parameters are not a {result.model} "
                          f"material ({e})") from None
    module = spec.module
    asked_model = target_model
    viewer = _implied_viewer(spec, viewer, target_model)
    target_model = _viewer_model(spec, viewer, target_model, result)
    if target_model is not None and target_model not in spec.shaded_as:
        raise ExportError(f"{target} carries {', '.join(spec.shaded_as)}, not {target_model!r}")
    models_wanted = ((target_model,) if target_model
                     else _by_layers_kept(spec.target_models, result))
    warnings: list[str] = []
    out_of_range = getattr(module, "out_of_range", lambda model, params: None)
    if result.model in models_wanted and (why := out_of_range(result.model, result.params)):
        if target_model is not None or len(models_wanted) == 1:
            raise ExportError(f"{why}: {spec.label} cannot load it; export it as another of "
                              f"its models ({', '.join(spec.target_models)})")
        models_wanted = tuple(m for m in models_wanted if m != result.model)
        warnings.append(f"range: {why}; refitted as {models_wanted[0]} instead")
    measured, fitted = None, False
    carried = result.model if result.model in models_wanted else models_wanted[0]
    if spec.shaded_as[carried] is not None:  # else nothing can be measured against it
        measured, fitted, missing = _measured_table(result, table)
        warnings += missing
    # the table the material is made from: the fitted one, where it is at hand; a table
    # given to judge the export against changed the material itself (a gold fit judged
    # against red-plastic was exported as red-plastic's dielectric)
    source = measured if fitted else None
    # an export for a viewer is that viewer's optimum on the measured table, where the
    # fit is not already of the viewer's model
    for_viewer = viewer != "spec" and source is not None
    conv = convert(result, models_wanted, measured=source if for_viewer else None)
    material_class = None
    if viewer == "spec" and target_model is None:
        # a plastic or a fabric is exported as a dielectric where the evidence says so
        conv, material_class = dielectric_or_mixture(result, conv, source)
    else:
        conv = half_metal_said(conv)
    # the brdffit model that evaluates the file as the renderer shades it, checked
    # against the renderer's own evaluation (None: the renderer's shading of this
    # node is not modelled, so nothing about it can be measured)
    shaded_as = spec.shaded_as[conv.target_model]
    warnings = list(conv.warnings) + warnings
    fidelity = conv.fidelity(result)
    # exact: the file's shading is the model, in a renderer's own evaluation; a glTF
    # file's is its spec's, where the spec defines the BRDF (KHR_materials_sheen leaves
    # it to the viewers: a gltf_sheen file was called exact, and no viewer shades it so)
    defined = not spec.viewers or shaded_as in module.VIEWER_MODELS["spec"]
    fidelity.update(exact=conv.exact and shaded_as == conv.target_model and defined,
                    renderer_model=shaded_as, log_rmse_to_table=None, sphere_colour=None,
                    render_psnr_db=None)
    if material_class is not None:
        fidelity["material_class"] = material_class
    if shaded_as is None:  # no table to read: nothing could be measured against it
        warnings.append(module.UNMODELLED_NOTE)
        measured = None
    if measured is not None:
        fidelity["log_rmse_to_table"] = table_error(measured, shaded_as, conv.params)["log_rmse"]
        # a sample list's fit is measured at its samples, its export on the bins they fall
        # in: the two figures are not the same error (an exact export read "0.009137 (the
        # fit's 0.01898)", as if it were twice better than its own fit)
        fidelity["measured_on"] = ("binned samples" if (result.input or {}).get("fitted_at")
                                   == "samples" else "table")
        fidelity.update(_sphere_figures(measured, models.get(shaded_as), conv.params))
    if spec.viewers and measured is not None:
        fidelity["viewers"] = _viewer_fidelity(spec, measured, conv.params, shaded_as,
                                               fidelity)
    warnings += (_looks_warning(result) + _renders_below_the_fit(result, fidelity)
                 + _layer_warning(result.model, conv, spec))
    energy, energy_warnings = energy_report(shaded_as or conv.target_model, conv.params)
    warnings += energy_warnings
    name = name or _material_name(result, viewer, asked_model)
    variants = None
    if spec.variants:  # both variant families' dictionaries, in the JSON too
        made = module.variants(conv.params)
        material, files, notes = module.write(conv.params, name, conv.target_model, made)
        variants = {"rgb": made[0], "spectral": made[1] if isinstance(made[1], dict) else None,
                    "for": dict(module.VARIANTS)}
    else:
        material, files, notes = module.write(conv.params, name, conv.target_model)
    return Export(target, result.model, spec.media_type, material, files,
                  {**fidelity, **energy}, conv.params, warnings + notes, result.table, variants)


def _layer_warning(source_model: str, conv, spec: ExportTarget) -> list[str]:
    """A warning where the fit has a layer (a coat, a sheen) that the exported model
    has not: the export is refitted without it, and its log_rmse to the fit is what
    that cost (with the rest of the conversion); where another of the target's models
    has the layer, it says which (Mitsuba's principled_clearcoat keeps a coat that its
    default, rough_conductor, has not: the warning read as if Mitsuba had no coat)."""
    from brdffit import models

    lost = [k for k in models.get(source_model).layers
            if k not in models.get(conv.target_model).layers]
    if not lost or conv.exact:
        return []
    what = " and ".join(lost)
    keeps = next((m for m in spec.target_models
                  if set(lost) <= set(models.get(m).layers)), None)
    kept = ("" if keeps is None else
            f"; {keeps} keeps it: export with target_model {keeps} (brdffit export "
            f"--target-model {keeps})")
    return [f"layer: the {what} of the {source_model} fit has no counterpart in "
            f"{conv.target_model}: refitted without it, log_rmse {conv.log_rmse_to_fit:.4g} "
            f"to the fit (the {what} lost, with the rest of the conversion){kept}"]


def _looks_warning(result: FitResult) -> list[str]:
    """A warning where the exported fit itself does not look good beside its table
    (its ``quality``): an export cannot look better than the fit it carries."""
    look = result.quality or {}
    if look.get("verdict") not in ("visible", "poor"):
        return []
    steps = look.get("next") or []
    hint = f"; next: {steps[0]['try']}" if steps else ""
    # "looks poor beside its table: ...", not "(... (poor below 20 dB))": a reason has
    # its own brackets
    return [f"the {result.model} fit looks {look['verdict']} beside its table: "
            f"{look.get('reason', '')}{hint}"]


#: How far (dB) an export's sphere may render below its fit's before it is said: 3 dB
#: is twice the squared error, a difference a person sees (the render rule's own margin).
RENDERS_BELOW_DB = 3.0


def _renders_below_the_fit(result: FitResult, fidelity: dict) -> list[str]:
    """A warning where the file's sphere renders well below the fit's own against the
    same table (a conversion's loss: nickel's render-loss rough_conductor left glTF at
    14.1 dB against the fit's 31.8, with no word but the refit's log_rmse)."""
    own = (result.quality or {}).get("render_psnr_db")
    got = fidelity.get("render_psnr_db")
    if own is None or got is None or got >= own - RENDERS_BELOW_DB:
        return []
    return [f"fidelity: the file's sphere renders {got:.1f} dB from the table, "
            f"{own - got:.1f} dB below the {result.model} fit's own {own:.1f} dB (what the "
            "conversion lost); fit the target's model to the table for an exact export"]


def _implied_viewer(target: ExportTarget, viewer: str, target_model: str | None) -> str:
    """The viewer an export is made for: a viewer's own model asked for without a viewer
    (``"spec"``, the default) is that viewer's export, refitted for its shading as
    ``viewer=`` makes it. It was a conversion to three.js's model that no viewer's fit
    made, while ``viewer="threejs"`` with Blender's model was refused."""
    by_viewer = getattr(target.module, "VIEWER_MODELS", {})
    if viewer != "spec" or target_model is None or target_model in by_viewer.get("spec", ()):
        return viewer
    return next((v for v, names in by_viewer.items() if target_model in names), viewer)


def _viewer_model(target: ExportTarget, viewer: str, target_model: str | None,
                  result: FitResult) -> str | None:
    """The target model an export for ``viewer`` carries (None: the target's default):
    ``target_model`` where the viewer shades it, else the viewer's model that keeps most
    of the layers ``result`` uses (a coat fit for three.js: three.js's coat), the
    viewer's core model first among equals (:func:`_by_layers_kept`)."""
    if viewer == "spec":
        return target_model
    if viewer not in target.viewers:
        # said of the export asked for: it read as the glTF export refusing the viewer
        # ("viewer 'threejs': the glTF export is made for ...; other targets have their
        # renderer's own") when a Mitsuba export was asked for one
        made_for = " or ".join(f"the {t.label} export ({', '.join(t.viewers)})"
                               for t in TARGETS.values() if t.viewers)
        if target.viewers:
            raise ExportError(f"viewer {viewer!r}: the {target.label} export's viewers are "
                              f"{', '.join(target.viewers)}")
        raise ExportError(f"viewer {viewer!r} is for {made_for}; a {target.label} export has "
                          "its renderer's own shading")
    shading = target.module.VIEWER_MODELS[viewer]
    if target_model is not None:
        if target_model not in shading:
            raise ExportError(f"viewer {viewer!r} carries {', '.join(shading)}, "
                              f"not {target_model!r}")
        return target_model
    return _by_layers_kept(shading, result)[0]


#: A layer whose weight (its largest channel) is at most this in a fit is not one the
#: fit uses: an export does not choose a layered model for it (a principled fit's sheen
#: at 0 stays a core glTF material).
LAYER_IN_USE = 1e-3


def _layers_in_use(result: FitResult) -> set[str]:
    """The kinds of layer (``AbstractBRDFModel.layers``) whose weight ``result`` holds
    above :data:`LAYER_IN_USE`."""
    from brdffit import models

    return {kind for kind, (weight, _) in models.get(result.model).layer_params.items()
            if float(np.max(np.abs(np.asarray(result.params[weight], float))))
            > LAYER_IN_USE}


def _by_layers_kept(candidates: tuple[str, ...], result: FitResult) -> tuple[str, ...]:
    """``candidates`` (a target's or a viewer's models, its core model first) reordered
    so that the model a conversion refits comes first: the one layered over the core
    (its ``parent``) that keeps most of the layers ``result`` uses, the core where none
    keeps any. A coat fit goes to MaterialX as ``standard_surface_coat``, to glTF as
    ``gltf_clearcoat``, to three.js's viewer as ``gltf_threejs_clearcoat``; to Mitsuba,
    whose coat is a dielectric's (``principled_clearcoat`` over ``principled``, not over
    its default ``rough_conductor``), as ``rough_conductor``, the coat named lost."""
    from brdffit import models

    used, core = _layers_in_use(result), candidates[0]

    def kept(name: str) -> int:
        m = models.get(name)
        return len(used & set(m.layers)) if name == core or m.parent == core else -1

    best = max(candidates, key=kept)  # the first among equals: the core
    return (best, *(m for m in candidates if m != best))


def _sphere_figures(measured, model, params: dict) -> dict:
    """The exported material's key-light sphere against the measured table's, as a
    fit's quality block measures its own (``SphereReference.psnr_and_colour``: the
    same renders, so an exact export's figures are its fit's): ``sphere_colour``
    (with the displayed brightness a verdict judges; the export reported the radiance
    one alone, 0.42 stops on a fit whose picture was 0.05 stops off) and
    ``render_psnr_db`` (None where not finite)."""
    import math

    from brdffit.fitting.problem import sphere_reference

    psnr, colour = sphere_reference(measured).psnr_and_colour(model, params)
    return {"sphere_colour": colour["key"],
            "render_psnr_db": float(psnr) if math.isfinite(psnr) else None}


def _viewer_fidelity(target: ExportTarget, measured, params: dict, shaded_as: str,
                     fidelity: dict) -> dict:
    """The glTF file's factors under each of ``target``'s viewers' shading, against the
    measured table: ``{viewer: {"model", "log_rmse_to_table", "sphere_colour"}}``; a
    viewer that reads some factors of the file and not others shades the ones it reads
    (Blender ignores ``KHR_materials_ior``: ``gltf.VIEWER_IGNORES``, said in
    ``"ignores"``). Of the viewer's models (``VIEWER_MODELS``: the spec's are its
    definition and the extensions that define their BRDF) the one whose parameters are
    the file's shades it; a viewer with none is null (three.js's ``gltf_threejs`` has
    no ``KHR_materials_ior``, which three.js shades with a physical material). The
    viewer whose model is ``shaded_as`` takes the export's own figures (``fidelity``),
    measured already."""
    from brdffit import models
    from brdffit.fitting.problem import table_error

    out = {}
    for viewer in target.viewers:
        ignored = [k for k in target.module.VIEWER_IGNORES.get(viewer, ()) if k in params]
        seen = {k: v for k, v in params.items() if k not in ignored}
        model = next((m for m in map(models.get, target.module.VIEWER_MODELS[viewer])
                      if {s.name for s in m.param_specs} == set(seen)), None)
        if model is None:
            out[viewer] = None
        elif model.name == shaded_as:
            out[viewer] = {"model": model.name,
                           **{k: fidelity[k] for k in ("log_rmse_to_table", "sphere_colour",
                                                       "render_psnr_db")}}
        else:
            out[viewer] = {"model": model.name,
                           "log_rmse_to_table": table_error(measured, model, seen)["log_rmse"],
                           **_sphere_figures(measured, model, seen)}
        if out[viewer] is not None and ignored:
            out[viewer]["ignores"] = ignored
    return out
